"""pick_place_executor: serves the pick_and_place action on top of the arm and gripper actions.

Thin: the sequence and its checks are in katana_manipulation.core.pick_place; this node only
offers them an arm port made of the two action clients (arm_controller/follow_joint_trajectory,
gripper_controller/gripper_command) and the joint_states subscription, so the sim or the real
driver can be underneath. Every wait is bounded in wall-clock time (for a server, for a goal to
be accepted, for a result) and ends at once when the node stops; a wait that runs out cancels
the goal and the action ends with TIMEOUT. No wait uses the ROS clock, so the node works the
same with use_sim_time (the fast sim runs many times faster than real time).

Callback groups: the action server's execute callback blocks while it waits on the clients, so
the server, the clients and the subscription live in separate groups and the node spins on a
MultiThreadedExecutor (its main() makes one).
"""

from __future__ import annotations

import math
import sys
import threading

from control_msgs.action import FollowJointTrajectory, GripperCommand
from katana_common.action_client import ActionClient
from katana_common.executor import MultiThreadedExecutor
from katana_common.futures import Stopped
from katana_common.messages import to_nanoseconds
from katana_common.node_runner import run_node
from katana_common.params import Param, declare_parameters
from katana_common.qos import JOINT_STATE_QOS
from katana_description import models as m
from katana_interfaces.action import PickAndPlace
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import JointState

from katana_manipulation.core import pick_place as pp
from katana_manipulation.core.kinematics import KatanaKinematics
from katana_manipulation.reach_params import REACH_PARAMS, planner_values
from katana_manipulation.ros_arm_port import ARM_ACTION, GRIPPER_ACTION, SETTLE_WAIT_S, RosArmPort

_DEFAULTS = pp.PickPlaceParams()
#: planner parameters applied live (the next goal plans with them): parameter -> planner field
LIVE_PLANNER_PARAMS = {"transit_height": "transit_height", "transit_radius": "transit_radius",
                       "speed_fraction": "speed_fraction",
                       "accel_fraction": "accel_fraction",
                       "min_segment_time_s": "min_segment_time"}
PARAMS = (
    Param("model", m.DEFAULT_MODEL, "Katana type (read-only: the kinematics are built once).",
          choices=tuple(sorted(m.MODELS))),
    *REACH_PARAMS,  # read-only, shared with the nodes that offer placements
    Param("transit_height", _DEFAULTS.transit_height, "Tool height while panning between "
          "places, m (the arm reaches 0.13 m top-down; the shoulder lifts the pads further).",
          0.05, 0.2, live=True),
    Param("transit_radius", _DEFAULTS.transit_radius, "Tool distance from the pan axis while "
          "panning, m.", 0.05, 0.3, live=True),
    Param("speed_fraction", _DEFAULTS.speed_fraction, "Fraction of each joint's speed limit at "
          "a move's peak.", 0.05, 1.0, live=True),
    Param("accel_fraction", _DEFAULTS.accel_fraction, "Fraction of each joint's acceleration "
          f"limit at a move's peak (the controller's {m.KNI_MAX_ACCELERATION} encoders per "
          "(10 ms)^2, which the arm contract and the driver enforce).", 0.05, 1.0, live=True),
    Param("min_segment_time_s", _DEFAULTS.min_segment_time, "Shortest trajectory segment, s. "
          f"The driver merges spline knots closer than {pp.MIN_SEGMENT_TIME_S} s, so shorter "
          "ones can speed the real arm up between points; the simulation runs "
          f"{pp.SIM_MIN_SEGMENT_TIME_S} (sim.yaml).", 0.02, 1.0, live=True),
    Param("park_pose", list(_DEFAULTS.park_pose), "Five arm joint angles out of the camera's "
          "view, rad (read-only).", -math.pi, math.pi, length=5),
    Param("server_timeout_s", 5.0, "Wall seconds to wait for an action server or a goal answer.",
          0.1, 120.0, live=True),
    Param("time_scale", 3.0, "A move may take this many times its planned duration (wall).",
          1.0, 1000.0, live=True),
    Param("timeout_margin_s", 10.0, "Plus this many wall seconds.", 0.0, 600.0, live=True),
)


def cross_check(values) -> str | None:
    """The park pose is within the joint limits of the model (start-up and live changes)."""
    why = KatanaKinematics(values["model"]).limit_violation(values["park_pose"])
    return f"parameter 'park_pose' is outside the joint limits: {why}" if why else None


def yaw_of(q) -> float:
    """Yaw about +z of a geometry_msgs Quaternion."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


class PickPlaceExecutor(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("pick_place_executor", **kwargs)
        self.params = declare_parameters(self, PARAMS, cross_check=cross_check)
        self.kin = KatanaKinematics(self.params["model"])
        self.planner = pp.PickPlacePlanner(self.kin, self._planner_params())
        self.params.on_change(self._on_params)
        self.stopping = threading.Event()
        self.state_lock = threading.Lock()
        self.latest_joints: dict[str, float] | None = None
        self.latest_joints_ns = -1  # the stamp of the joint_states that last completed them
        self._busy = threading.Lock()
        self._reset_ns = 0  # the latest joint_states_after a goal carried (a reset's stamp)
        clients = ReentrantCallbackGroup()
        self.arm_client = ActionClient(self, FollowJointTrajectory, ARM_ACTION,
                                       callback_group=clients)
        self.gripper_client = ActionClient(self, GripperCommand, GRIPPER_ACTION,
                                           callback_group=clients)
        self.create_subscription(JointState, "joint_states", self._on_joints, JOINT_STATE_QOS,
                                 callback_group=MutuallyExclusiveCallbackGroup())
        self.server = ActionServer(
            self, PickAndPlace, "pick_and_place", execute_callback=self._execute,
            goal_callback=lambda _g: GoalResponse.ACCEPT,  # checked in execute, with a reason
            cancel_callback=lambda _g: CancelResponse.ACCEPT,
            callback_group=ReentrantCallbackGroup())
        self.port = RosArmPort(self)

    def _planner_params(self) -> pp.PickPlaceParams:
        return pp.PickPlaceParams(park_pose=list(self.params["park_pose"]),
                                  **planner_values(self.params),
                                  **{field: self.params[name]
                                     for name, field in LIVE_PLANNER_PARAMS.items()})

    def _on_params(self, changed: dict) -> None:
        if any(k in LIVE_PLANNER_PARAMS for k in changed):  # the next goal plans with them
            self.planner = pp.PickPlacePlanner(self.kin, self._planner_params())

    def stop(self) -> None:
        """End every wait at once (run_node calls this on shutdown)."""
        self.stopping.set()

    def _on_joints(self, msg: JointState) -> None:
        if len(msg.name) != len(msg.position):
            self.get_logger().warning("joint_states with names and positions of unequal length",
                                      throttle_duration_sec=5.0)
            return
        with self.state_lock:
            merged = dict(self.latest_joints or {})
            merged.update(zip(msg.name, msg.position, strict=True))
            if all(n in merged for n in m.ALL_JOINTS):
                self.latest_joints = merged
                self.latest_joints_ns = to_nanoseconds(msg.header.stamp)

    def _feedback(self, goal_handle):
        def publish(phase: str, progress: float) -> None:
            if self.stopping.is_set():
                return
            try:
                goal_handle.publish_feedback(PickAndPlace.Feedback(phase=phase,
                                                                   progress=float(progress)))
            except Exception:  # the context went down under us (a signal)
                if self.context.ok():
                    raise
                self.stopping.set()
        return publish

    def _execute(self, goal_handle):
        g = goal_handle.request
        if not self._busy.acquire(blocking=False):
            out = pp.PickPlaceResult(False, pp.ABORTED, "another pick_and_place is running")
            return self._finish(goal_handle, g, out)
        try:
            after_ns = to_nanoseconds(g.joint_states_after)
            if after_ns > 0 and self.port.joint_positions(after_ns) is None:
                # the arm was moved outside this action (a world reset): plan from where it is
                out = pp.PickPlaceResult(False, pp.TIMEOUT, "no joint_states stamped at or "
                                         f"after {after_ns / 1e9:.3f} s (joint_states_after)")
                return self._finish(goal_handle, g, out)
            # the same joint_states_after as the task before: no reset since, the arm stands
            # where that task left it
            if (after_ns <= self._reset_ns and not self.port.settled()
                    and not self.stopping.is_set()):
                self.get_logger().info(
                    f"joint_states do not show the arm where the last task left it after "
                    f"{SETTLE_WAIT_S:g} s: planning from where they show it")
            self._reset_ns = max(self._reset_ns, after_ns)
            req = pp.PickPlaceRequest(
                pick=(g.pick.position.x, g.pick.position.y, g.pick.position.z),
                pick_yaw=yaw_of(g.pick.orientation),
                block_size=(g.block_size.x, g.block_size.y, g.block_size.z),
                place=(g.place.position.x, g.place.position.y, g.place.position.z),
                place_yaw=yaw_of(g.place.orientation),
            )
            out = pp.execute_pick_place(
                req, self.port, self.planner, self._feedback(goal_handle),
                cancelled=lambda: goal_handle.is_cancel_requested or self.stopping.is_set())
        except Stopped:
            out = pp.PickPlaceResult(False, pp.ABORTED, "the executor is shutting down")
        except Exception as exc:  # a malformed goal must never take the node down
            out = pp.PickPlaceResult(False, pp.INVALID_GOAL, f"bad goal: {exc}")
        finally:
            self._busy.release()
        return self._finish(goal_handle, g, out)

    def _finish(self, goal_handle, goal, out: pp.PickPlaceResult) -> PickAndPlace.Result:
        result = PickAndPlace.Result(success=out.success, error_code=out.code,
                                     message=out.message)
        label = goal.block_id or "block"
        try:
            if out.success:
                self.get_logger().info(f"pick_and_place {label}: placed")
                goal_handle.succeed()
            elif out.code == pp.ABORTED and goal_handle.is_cancel_requested:
                goal_handle.canceled()
            else:
                self.get_logger().warning(f"pick_and_place {label}: {out.message}")
                goal_handle.abort()
        except Exception:  # the context is gone (shutdown): nobody is left to tell
            if not self.stopping.is_set():
                raise
        return result


def main(args: list[str] | None = None) -> int:
    return run_node(PickPlaceExecutor, "pick_place_executor", args,
                    executor_factory=lambda: MultiThreadedExecutor(num_threads=4))


if __name__ == "__main__":
    sys.exit(main())
