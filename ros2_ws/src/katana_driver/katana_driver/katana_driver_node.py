"""katana_driver_node: the real Katana behind the same interfaces as sim_node.

Publishes joint_states (polled at poll_rate once the arm is calibrated; wall-time stamps of
the poll) and arm_ready (std_msgs/Bool, transient-local: true while connected and calibrated);
serves arm_controller/follow_joint_trajectory, gripper_controller/gripper_command, ~/set_motors
and ~/reset_world (an operator must reset the blocks). Goals are judged by
katana_description.arm_contract, as in the simulation, and run by core.motion on the
core.arm.ArmWorker thread that owns the link; callbacks wait, so a MultiThreadedExecutor.
"""

from __future__ import annotations

import sys
import threading
import time

from control_msgs.action import FollowJointTrajectory, GripperCommand
from katana_common.diagnostics import Diagnostics
from katana_common.executor import MultiThreadedExecutor
from katana_common.messages import time_msg, trajectory_goal
from katana_common.node_runner import run_node
from katana_common.params import declare_parameters
from katana_common.qos import JOINT_STATE_QOS, STATE_QOS
from katana_description import arm_contract as ac
from katana_description import gripper_contract as gc
from katana_interfaces.srv import ResetWorld, SetMotors
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool

from katana_driver import messages as msgs
from katana_driver.core import motion
from katana_driver.core.arm import ArmState, ArmWorker
from katana_driver.core.encoders import ALL_JOINTS, EncoderModel
from katana_driver.core.transport import make_transport
from katana_driver.driver_params import PARAMS, cross_check
from katana_driver.health import driver_health


class KatanaDriverNode(Node):
    """Thin ROS layer over ArmWorker and core.motion: messages in, core calls, messages out."""

    def __init__(self, **kwargs) -> None:
        kwargs.setdefault("node_name", "katana_driver_node")
        super().__init__(**kwargs)
        self.params = params = declare_parameters(self, PARAMS, cross_check)
        # the model parameter picks the KNI numbers (Katana type) and the gripper variant
        self.model = EncoderModel.for_model(params["model"])
        self.contract = self._contract()
        self._stop = threading.Event()
        self.worker = ArmWorker(
            make_transport(params["transport"], params["host"], params["port"],
                           params["serial_device"], timeout=params["timeout"],
                           retries=params["retries"]),
            self.model, poll_rate=params["poll_rate"],
            calibrate_on_start=params["calibrate_on_startup"],
            collision_detection=params["collision_detection"],
            reconnect_period=params["reconnect_period"],
            calibration_timeout=params["calibration_timeout"],
            on_state=self._publish_state, log=self._log,
            limit_margin=params["limit_margin_encoders"], speed_limits=params["speed_limits"],
            acceleration_limits=params["acceleration_limits"],
        )
        params.on_change(self._apply)
        self._flags = threading.Lock()  # one goal (arm or gripper) at a time
        self._arm_active = self._gripper_active = False
        self._joint_pub = self.create_publisher(JointState, "joint_states", JOINT_STATE_QOS)
        self._ready_pub = self.create_publisher(Bool, "arm_ready", STATE_QOS)
        self._ready: bool | None = None
        group = ReentrantCallbackGroup()
        cancel = lambda _: CancelResponse.ACCEPT  # noqa: E731
        ActionServer(self, FollowJointTrajectory, "arm_controller/follow_joint_trajectory",
                     execute_callback=self._execute_arm, goal_callback=self._arm_goal,
                     cancel_callback=cancel, callback_group=group)
        ActionServer(self, GripperCommand, "gripper_controller/gripper_command",
                     execute_callback=self._execute_gripper, cancel_callback=cancel,
                     callback_group=group)
        self.create_service(SetMotors, "~/set_motors", self._set_motors, callback_group=group)
        self.create_service(ResetWorld, "~/reset_world", self._reset_world, callback_group=group)
        self.create_timer(0.2, self._publish_ready, callback_group=group)
        self.diagnostics = Diagnostics(self, {"controller": lambda: driver_health(self.worker)},
                                       hardware_id=f"katana {params['model']}")
        self.worker.start()
        self.get_logger().info(f"Katana {params['model']} over {self.worker.transport.name}; "
                               f"polling at {params['poll_rate']:g} Hz")

    def _contract(self) -> ac.ArmContract:
        p = self.params
        return ac.ArmContract(
            model=p["model"], max_trajectory_s=p["max_trajectory_s"],
            default_goal_tolerance_rad=p["goal_tolerance"],
            default_goal_time_tolerance_s=p["goal_time_tolerance"],
            gripper_tolerance_rad=p["gripper_tolerance"],
            gripper_stall_time_s=p["gripper_stall_time"],
            limit_margin_enc=p["limit_margin_encoders"],
            acceleration_limits=tuple(float(a) for a in p["acceleration_limits"][:5]))

    def _apply(self, changed: dict) -> None:
        self.contract = self._contract()
        if "poll_rate" in changed:
            self.worker.period = 1.0 / changed["poll_rate"]
        if "reconnect_period" in changed:
            self.worker.reconnect_period = changed["reconnect_period"]

    def _log(self, level: str, message: str) -> None:
        logger = self.get_logger()  # one call site per severity (rclpy insists)
        if level in ("debug", "info"):
            logger.info(message) if level == "info" else logger.debug(message)
        else:
            logger.warning(message) if level == "warn" else logger.error(message)

    def _publish_state(self, state: ArmState) -> None:
        if not self.worker.calibrated:  # uncalibrated encoders mean nothing
            return
        msg = JointState(name=list(ALL_JOINTS), position=[float(x) for x in state.positions],
                         velocity=[float(x) for x in state.velocities])
        msg.header.stamp = time_msg(time.time() - (time.monotonic() - state.stamp))
        try:
            self._joint_pub.publish(msg)
        except Exception:  # noqa: BLE001 - the context may be shutting down
            pass

    def _publish_ready(self) -> None:
        ready = self.worker.ready
        if ready != self._ready:
            self._ready = ready
            self._ready_pub.publish(Bool(data=ready))
            self.get_logger().info("arm ready" if ready else "arm not ready")

    def stop(self) -> None:
        """Freeze a moving arm, end every wait and the worker thread (run_node calls it)."""
        if self._stop.is_set():
            return
        self._stop.set()
        if self.worker.connected:  # hold where it is (harmless when idle): stop any motion
            try:
                self.worker.stop_motion().result(timeout=0.8)
            except Exception:  # noqa: BLE001 - shutting down: the worker's close ends the link
                pass
        self.worker.stop(timeout=0.5)  # with the executor's 0.5 s: within a node's 2 s to end

    def destroy_node(self) -> None:
        self.stop()
        super().destroy_node()

    # ------------------------------------------------------------------ actions
    def _arm_goal(self, _goal) -> GoalResponse:
        if not self._arm_active:
            return GoalResponse.ACCEPT
        self.get_logger().warning("trajectory goal rejected: another trajectory is running")
        return GoalResponse.REJECT

    def _claim(self, arm: bool) -> str:
        """Mark an arm or gripper goal active; the reason it may not run now, or ''."""
        with self._flags:
            if self._arm_active:
                return "an arm trajectory is running; send the goal after it"
            if self._gripper_active:
                return "a gripper goal is running; send the goal after it"
            if arm:
                self._arm_active = True
            else:
                self._gripper_active = True
            return ""

    def _execute_arm(self, goal_handle) -> FollowJointTrajectory.Result:
        goal = trajectory_goal(goal_handle.request)
        busy = "" if isinstance(goal, ac.Verdict) else self._claim(arm=True)
        if isinstance(goal, ac.Verdict) or busy:
            refusal = goal if not busy else ac.Verdict(ac.INVALID_GOAL, busy)
            outcome = ac.Outcome(ac.ABORTED, refusal.error_code, refusal.error_string)
        else:
            try:
                with self.worker.busy():
                    outcome = motion.run_trajectory(
                        self.worker, self.model, self.contract, goal,
                        lambda: goal_handle.is_cancel_requested,
                        lambda fb: self._feedback(goal_handle, msgs.trajectory_feedback(
                            fb, self.get_clock().now().to_msg())),
                        self._stop)
            finally:
                self._arm_active = False
        return self._finish(goal_handle, outcome, msgs.trajectory_result(outcome), "trajectory")

    def _execute_gripper(self, goal_handle) -> GripperCommand.Result:
        goal = msgs.gripper_goal(goal_handle.request)
        verdict = gc.validate_gripper(goal)
        busy = self._claim(arm=False) if verdict.ok else verdict.error_string
        if busy:
            state = self.worker.state
            position = state.positions[5] if state is not None else 0.0
            outcome = gc.GripperOutcome(ac.ABORTED, position, message=busy)
        else:
            try:
                with self.worker.busy():
                    outcome = motion.run_gripper(
                        self.worker, self.model, self.contract, goal, False,
                        lambda: goal_handle.is_cancel_requested,
                        lambda o: self._feedback(goal_handle, msgs.gripper_feedback(o)),
                        self._stop)
            finally:
                self._gripper_active = False
        return self._finish(goal_handle, outcome, msgs.gripper_result(outcome), "gripper goal")

    def _feedback(self, goal_handle, msg) -> None:
        try:
            goal_handle.publish_feedback(msg)
        except Exception:  # noqa: BLE001 - a signal shut the context down: stop() follows
            if not self._stop.is_set() and self.context.ok():
                raise

    def _finish(self, goal_handle, outcome, result, what: str):
        try:
            if outcome.status == ac.SUCCEEDED:
                goal_handle.succeed()
            elif outcome.status == ac.CANCELED and goal_handle.is_cancel_requested:
                goal_handle.canceled()
            else:
                if not self._stop.is_set():
                    self.get_logger().warning(f"{what} not done: {outcome.message}")
                goal_handle.abort()
        except Exception:  # noqa: BLE001 - shutting down: the action server is gone
            if not self._stop.is_set():
                raise
        return result

    def _set_motors(self, request: SetMotors.Request, response: SetMotors.Response):
        def switch(client):  # on: hold where it is; off: empty the buffers, then limp
            if request.enable:
                return client.hold_all(client.read_positions())
            client.flush_buffers()
            client.motors_off()

        try:
            self.worker.call(switch)
        except Exception as exc:  # noqa: BLE001 - reported to the caller
            response.success, response.message = False, f"could not switch the motors: {exc}"
            return response
        response.success = True
        response.message = "motors on (holding)" if request.enable else "motors off (limp)"
        self.get_logger().info(response.message)
        return response

    def _reset_world(self, _request: ResetWorld.Request, response: ResetWorld.Response):
        response.success, response.message = False, msgs.RESET_MESSAGE
        self.get_logger().warning(msgs.RESET_MESSAGE)
        return response


def main(args: list[str] | None = None) -> int:
    return run_node(KatanaDriverNode, "katana_driver_node", args, shutdown_timeout_s=0.5,
                    executor_factory=lambda: MultiThreadedExecutor(num_threads=4))


if __name__ == "__main__":
    sys.exit(main())
