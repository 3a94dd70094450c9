"""pick_place_executor: serves the pick_and_place action on top of the arm and gripper actions.

Thin: the sequence and its checks are in katana_manipulation.core.pick_place; this node only
offers them an arm port made of the two action clients (arm_controller/follow_joint_trajectory,
gripper_controller/gripper_command) and the joint_states subscription, so the sim or the real
driver can be underneath. Every wait is bounded (waiting for a server, for a goal to be accepted,
for a result); a wait that runs out cancels the goal and the action ends with TIMEOUT.

Callback groups: the action server's execute callback blocks while it waits on the clients, so
the server, the clients and the subscription live in separate reentrant groups and the node must
spin on a MultiThreadedExecutor with at least four threads (its main() makes one).
"""

from __future__ import annotations

import math
import sys
import threading
import time

import rclpy
from builtin_interfaces.msg import Duration
from katana_description import models as m
from katana_interfaces.action import FollowJointTrajectory, GripperCommand, PickAndPlace
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.action import ActionClient, ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectoryPoint

from katana_manipulation.core import pick_place as pp
from katana_manipulation.core.kinematics import KatanaKinematics

ARM_ACTION = "arm_controller/follow_joint_trajectory"
GRIPPER_ACTION = "gripper_controller/gripper_command"


def _yaw(q) -> float:
    """Yaw about +z of a geometry_msgs Quaternion."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _duration(t: float) -> Duration:
    sec = int(math.floor(t))
    return Duration(sec=sec, nanosec=int((t - sec) * 1e9))


def _wait_future(future, timeout: float) -> bool:
    """Block until the rclpy future is done (True) or the timeout passes (False)."""
    done = threading.Event()
    future.add_done_callback(lambda _f: done.set())
    return done.wait(timeout) or future.done()


class RosArmPort:
    """pp.ArmPort over the arm and gripper actions; every call returns within its bound."""

    def __init__(self, node: PickPlaceExecutor) -> None:
        self.node = node

    def _send(self, client: ActionClient, name: str, goal, result_timeout: float):
        """(result, '') or (None, why) for a refusal or ("timeout", why) for a wait that ran out."""
        n = self.node
        if not client.wait_for_server(timeout_sec=n.server_timeout):
            return "timeout", f"action server {name} not available"
        send = client.send_goal_async(goal)
        if not _wait_future(send, n.server_timeout):
            return "timeout", f"{name}: no answer to the goal"
        handle = send.result()
        if handle is None or not handle.accepted:
            return None, f"{name}: goal rejected"
        res = handle.get_result_async()
        if not _wait_future(res, result_timeout):
            handle.cancel_goal_async()
            return "timeout", f"{name}: no result within {result_timeout:.1f} s"
        return res.result(), ""

    def move(self, points: list[list[float]], times: list[float],
             velocities: list[list[float]] | None = None) -> pp.MoveResult:
        goal = FollowJointTrajectory.Goal()
        goal.trajectory.joint_names = list(m.ARM_JOINTS)
        vels = velocities or [[] for _ in points]
        goal.trajectory.points = [
            JointTrajectoryPoint(positions=list(q), velocities=list(v),
                                 time_from_start=_duration(t))
            for q, v, t in zip(points, vels, times, strict=True)
        ]
        timeout = times[-1] * self.node.time_scale + self.node.timeout_margin
        res, why = self._send(self.node.arm_client, ARM_ACTION, goal, timeout)
        if res is None or res == "timeout":
            return pp.MoveResult(False, why, timed_out=res == "timeout")
        if res.result.error_code != FollowJointTrajectory.Result.SUCCESSFUL:
            msg = res.result.error_string or f"error code {res.result.error_code}"
            return pp.MoveResult(False, msg)
        return pp.MoveResult(True)

    def grip(self, position: float, effort: float) -> pp.GripResult:
        goal = GripperCommand.Goal()
        goal.command.position = float(position)
        goal.command.max_effort = float(effort)
        timeout = 3.0 * self.node.time_scale + self.node.timeout_margin
        res, why = self._send(self.node.gripper_client, GRIPPER_ACTION, goal, timeout)
        if res is None or res == "timeout":
            return pp.GripResult(False, message=why, timed_out=res == "timeout")
        r = res.result
        ok = res.status == 4  # GoalStatus.STATUS_SUCCEEDED
        return pp.GripResult(ok, r.position, r.stalled, r.reached_goal,
                             "" if ok else f"gripper goal ended with status {res.status}")

    def joint_positions(self) -> dict[str, float] | None:
        deadline = time.monotonic() + self.node.server_timeout
        while time.monotonic() < deadline:
            with self.node.state_lock:
                latest = self.node.latest_joints
            if latest is not None:
                return dict(latest)
            time.sleep(0.01)
        return None


class PickPlaceExecutor(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("pick_place_executor", **kwargs)
        d = self._declare
        d("model", m.DEFAULT_MODEL, f"Katana type: one of {sorted(m.MODELS)}")
        d("approach_height", 0.06, "descend onto a block from this far above (m)", 0.01, 0.2)
        d("transit_height", 0.125, "tool height while panning between places (m)", 0.05, 0.2)
        d("transit_radius", 0.12, "tool distance from the pan axis while panning (m)", 0.05, 0.3)
        d("grasp_offset", 0.003, "tool point above the block centre when grasping (m)", -0.02, 0.02)
        d("speed_fraction", 0.9, "fraction of each joint's speed limit at a move's peak", 0.05, 1.0)
        d("park_pose", list(m.PARK_POSE), "five arm joint angles out of the camera's view (rad)")
        d("server_timeout", 5.0, "wall seconds to wait for an action server or a goal answer",
          0.1, 120.0)
        d("time_scale", 3.0, "a move may take this many times its planned duration (wall)",
          1.0, 1000.0)
        d("timeout_margin", 10.0, "plus this many wall seconds", 0.0, 600.0)
        g = self.get_parameter
        params = pp.PickPlaceParams(
            approach_height=g("approach_height").value,
            transit_height=g("transit_height").value,
            transit_radius=g("transit_radius").value,
            grasp_offset=g("grasp_offset").value,
            speed_fraction=g("speed_fraction").value,
            park_pose=list(g("park_pose").value),
        )
        kin = KatanaKinematics(g("model").value)  # ValueError names the model
        if len(params.park_pose) != 5 or kin.limit_violation(params.park_pose) is not None:
            raise ValueError(f"parameter 'park_pose': five angles within the joint limits, got "
                             f"{params.park_pose}")
        self.planner = pp.PickPlacePlanner(kin, params)
        self.server_timeout = g("server_timeout").value
        self.time_scale = g("time_scale").value
        self.timeout_margin = g("timeout_margin").value

        self.state_lock = threading.Lock()
        self.latest_joints: dict[str, float] | None = None
        self._busy = threading.Lock()
        clients = ReentrantCallbackGroup()
        self.arm_client = ActionClient(self, FollowJointTrajectory,
                                       ARM_ACTION, callback_group=clients)
        self.gripper_client = ActionClient(self, GripperCommand,
                                           GRIPPER_ACTION, callback_group=clients)
        self.create_subscription(JointState, "joint_states", self._on_joints, 10,
                                 callback_group=MutuallyExclusiveCallbackGroup())
        self.server = ActionServer(
            self, PickAndPlace, "pick_and_place", execute_callback=self._execute,
            goal_callback=self._on_goal, cancel_callback=lambda _g: CancelResponse.ACCEPT,
            callback_group=ReentrantCallbackGroup())
        self.port = RosArmPort(self)

    def _declare(self, name, value, text, lo=None, hi=None) -> None:
        desc = ParameterDescriptor(description=text)
        if lo is not None:
            desc.floating_point_range = [FloatingPointRange(from_value=lo, to_value=hi, step=0.0)]
        self.declare_parameter(name, value, desc)

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

    def _on_goal(self, _goal) -> GoalResponse:
        return GoalResponse.ACCEPT  # checked in execute, so a refusal carries its reason

    def _execute(self, goal_handle):
        g = goal_handle.request
        result = PickAndPlace.Result()
        if not self._busy.acquire(blocking=False):
            result.success, result.error_code = False, PickAndPlace.Result.ABORTED
            result.message = "another pick_and_place is running"
            goal_handle.abort()
            return result
        try:
            req = pp.PickPlaceRequest(
                pick=(g.pick.position.x, g.pick.position.y, g.pick.position.z),
                pick_yaw=_yaw(g.pick.orientation),
                block_size=(g.block_size.x, g.block_size.y, g.block_size.z),
                place=(g.place.position.x, g.place.position.y, g.place.position.z),
                place_yaw=_yaw(g.place.orientation),
            )

            def feedback(phase: str, progress: float) -> None:
                goal_handle.publish_feedback(PickAndPlace.Feedback(phase=phase,
                                                                   progress=float(progress)))

            out = pp.execute_pick_place(req, self.port, self.planner, feedback,
                                        cancelled=lambda: goal_handle.is_cancel_requested)
        except Exception as exc:  # a malformed goal must never take the node down
            out = pp.PickPlaceResult(False, pp.INVALID_GOAL, f"bad goal: {exc}")
        finally:
            self._busy.release()
        result.success, result.error_code, result.message = out.success, out.code, out.message
        label = g.block_id or "block"
        if out.success:
            self.get_logger().info(f"pick_and_place {label}: placed")
            goal_handle.succeed()
        else:
            self.get_logger().warning(f"pick_and_place {label}: {out.message}")
            if out.code == pp.ABORTED and goal_handle.is_cancel_requested:
                goal_handle.canceled()
            else:
                goal_handle.abort()
        return result


def main(args: list[str] | None = None) -> int:
    rclpy.init(args=args)
    try:
        node = PickPlaceExecutor()
    except Exception as exc:  # invalid parameters: say which, exit non-zero
        print(f"pick_place_executor: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    executor = MultiThreadedExecutor(num_threads=4)
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
