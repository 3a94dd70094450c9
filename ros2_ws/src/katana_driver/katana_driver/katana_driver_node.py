"""katana_driver_node: the real Katana behind the same interfaces as sim_node.

Publishes joint_states (polled at up to 25 Hz), serves arm_controller/follow_joint_trajectory,
gripper_controller/gripper_command, ~/set_motors and ~/reset_world (which answers that an
operator must reset the blocks). All I/O runs in core.arm.ArmWorker's thread; callbacks only
post jobs and wait on futures or cached state, so run it on a MultiThreadedExecutor (the
action callbacks wait for the arm to finish; give the executor at least three threads).
"""

from __future__ import annotations

import math
import sys
import threading
import time

import rclpy
from builtin_interfaces.msg import Duration
from katana_interfaces.action import FollowJointTrajectory, GripperCommand
from katana_interfaces.srv import ResetWorld, SetMotors
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectoryPoint

from katana_driver.core import protocol as proto
from katana_driver.core.arm import ArmState, ArmWorker
from katana_driver.core.encoders import ALL_JOINTS, ARM_JOINTS, KATANA_TYPES, VARIANTS, EncoderModel
from katana_driver.core.splines import TrajectoryError, plan_trajectory
from katana_driver.core.transport import TransportError, make_transport
from katana_driver.params import declare

RESET_MESSAGE = (
    "hardware backend: the blocks cannot be reset by software; an operator must scatter them "
    "by hand in the play area, then continue"
)
DONE_STATUS = (proto.STATUS_HOLDING, proto.STATUS_SPLINE_DONE)


def _seconds(d: Duration) -> float:
    return d.sec + d.nanosec * 1e-9


def _duration(seconds: float) -> Duration:
    sec = math.floor(seconds)
    return Duration(sec=int(sec), nanosec=int((seconds - sec) * 1e9))


class KatanaDriverNode(Node):
    """Thin ROS layer over ArmWorker: messages in, core calls, messages out."""

    def __init__(self, **kwargs) -> None:
        kwargs.setdefault("node_name", "katana_driver_node")
        super().__init__(**kwargs)
        self.katana_type = declare(
            self,
            "katana_type",
            450,
            "Katana model: 300 (serial) or 400/450 (TCP)",
            choices=KATANA_TYPES,
        )
        self.variant = declare(
            self,
            "variant",
            "6M180",
            "gripper variant (6M180 in line, 6M90A/6M90B angled)",
            choices=VARIANTS,
        )
        transport = declare(
            self,
            "transport",
            "tcp",
            "link to the controller: tcp (400/450) or serial (300)",
            choices=("tcp", "serial"),
        )
        host = declare(self, "host", "192.168.1.1", "controller address (TCP)")
        port = declare(self, "port", 5566, "controller TCP port", 1, 65535)
        device = declare(self, "serial_device", "/dev/ttyUSB0", "serial device (Katana 300)")
        calibrate = declare(
            self,
            "calibrate_on_startup",
            True,
            "calibrate when the arm is not calibrated (needed after every power-on)",
        )
        poll_rate = declare(self, "poll_rate", 25.0, "joint_states polling rate, Hz", 1.0, 50.0)
        timeout = declare(self, "timeout", 0.5, "reply timeout per attempt, s", 0.05, 10.0)
        retries = declare(self, "retries", 3, "re-sends on a short reply or bad CRC", 0, 10)
        reconnect = declare(self, "reconnect_period", 1.0, "s between reconnections", 0.1, 60.0)
        collision = declare(
            self, "collision_detection", True, "let the controller stop the arm on a collision"
        )
        calib_timeout = declare(
            self, "calibration_timeout", 120.0, "longest calibration run, s", 1.0, 600.0
        )
        self.goal_tolerance = declare(
            self, "goal_tolerance", 0.01, "default final position tolerance, rad", 0.001, 0.5
        )
        self.goal_time_tolerance = declare(
            self,
            "goal_time_tolerance",
            1.0,
            "default extra time to settle at the goal, s",
            0.0,
            30.0,
        )
        self.gripper_tolerance = declare(
            self, "gripper_tolerance", 0.01, "gripper position tolerance, rad", 0.001, 0.2
        )
        self.stall_time = declare(
            self,
            "gripper_stall_time",
            0.5,
            "the gripper is stalled (holding something) when it has not moved for this long, s",
            0.1,
            10.0,
        )
        if transport == "serial" and self.katana_type != 300:
            self.get_logger().warning("serial transport is the Katana 300's; 400/450 use TCP")

        self.model = EncoderModel(self.variant)
        self.worker = ArmWorker(
            make_transport(transport, host, port, device, timeout=timeout, retries=retries),
            self.model,
            poll_rate=poll_rate,
            calibrate_on_start=calibrate,
            collision_detection=collision,
            reconnect_period=reconnect,
            calibration_timeout=calib_timeout,
            on_state=self._publish_state,
            log=self._log,
        )
        self._motion_lock = threading.Lock()
        self._arm_active = False
        self._gripper_active = False

        state_qos = QoSProfile(
            depth=1,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        self._joint_pub = self.create_publisher(JointState, "joint_states", state_qos)
        group = ReentrantCallbackGroup()
        self._arm_server = ActionServer(
            self,
            FollowJointTrajectory,
            "arm_controller/follow_joint_trajectory",
            execute_callback=self._execute_arm,
            goal_callback=self._arm_goal,
            cancel_callback=lambda _: CancelResponse.ACCEPT,
            callback_group=group,
        )
        self._gripper_server = ActionServer(
            self,
            GripperCommand,
            "gripper_controller/gripper_command",
            execute_callback=self._execute_gripper,
            goal_callback=self._gripper_goal,
            cancel_callback=lambda _: CancelResponse.ACCEPT,
            callback_group=group,
        )
        self.create_service(SetMotors, "~/set_motors", self._set_motors, callback_group=group)
        self.create_service(ResetWorld, "~/reset_world", self._reset_world, callback_group=group)
        self.worker.start()
        self.get_logger().info(
            f"Katana {self.katana_type} {self.variant} over {self.worker.transport.name}; "
            f"polling at {poll_rate:g} Hz"
        )

    # ------------------------------------------------------------------ plumbing
    def _log(self, level: str, message: str) -> None:
        # One call site per severity: rclpy refuses a severity change at one call site.
        logger = self.get_logger()
        if level == "debug":
            logger.debug(message)
        elif level == "info":
            logger.info(message)
        elif level == "warn":
            logger.warning(message)
        else:
            logger.error(message)

    def _publish_state(self, state: ArmState) -> None:
        msg = JointState()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.name = list(ALL_JOINTS)
        msg.position = [float(x) for x in state.positions]
        msg.velocity = [float(x) for x in state.velocities]
        try:
            self._joint_pub.publish(msg)
        except Exception:  # noqa: BLE001 - the context may be shutting down
            pass

    def _ready_problem(self) -> str:
        if not self.worker.connected:
            return f"no connection to the Katana controller ({self.worker.link_error})"
        if not self.worker.calibrated:
            return "the arm is not calibrated; restart the driver with calibrate_on_startup:=true"
        if self.worker.state is None:
            return "no joint state read from the arm yet"
        return ""

    def destroy_node(self) -> None:
        self.worker.stop()
        super().destroy_node()

    # ------------------------------------------------------------------ arm
    def _arm_goal(self, goal: FollowJointTrajectory.Goal) -> GoalResponse:
        if self._arm_active:
            self.get_logger().warning("trajectory goal rejected: another trajectory is running")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _execute_arm(self, goal_handle) -> FollowJointTrajectory.Result:
        result = FollowJointTrajectory.Result()
        self._arm_active = True
        try:
            with self._motion_lock, self.worker.busy():
                code, text = self._run_trajectory(goal_handle)
        finally:
            self._arm_active = False
        result.error_code, result.error_string = code, text
        if goal_handle.is_cancel_requested:
            goal_handle.canceled()
        elif code == FollowJointTrajectory.Result.SUCCESSFUL:
            goal_handle.succeed()
        else:
            self.get_logger().warning(f"trajectory not done: {text}")
            goal_handle.abort()
        return result

    def _run_trajectory(self, goal_handle) -> tuple[int, str]:
        R = FollowJointTrajectory.Result
        goal = goal_handle.request
        traj = goal.trajectory
        names = list(traj.joint_names)
        if sorted(names) != sorted(ARM_JOINTS):
            return R.INVALID_JOINTS, f"joint_names must be the five arm joints {list(ARM_JOINTS)}"
        if not traj.points:
            return R.INVALID_GOAL, "the trajectory has no points"
        order = [names.index(j) for j in ARM_JOINTS]
        try:
            times = [_seconds(pt.time_from_start) for pt in traj.points]
            positions = [[pt.positions[i] for i in order] for pt in traj.points]
            with_vel = all(len(pt.velocities) == len(names) for pt in traj.points)
            velocities = (
                [[pt.velocities[i] for i in order] for pt in traj.points] if with_vel else None
            )
        except IndexError:
            return R.INVALID_GOAL, "every point needs one position per joint"
        problem = self._ready_problem()
        if problem:
            return R.INVALID_GOAL, problem
        state = self.worker.state
        try:
            plan = plan_trajectory(self.model, state.encoders, times, positions, velocities)
        except TrajectoryError as exc:
            return R.INVALID_GOAL, str(exc)
        goal_tol, path_tol = self._tolerances(goal)
        settle = _seconds(goal.goal_time_tolerance) or self.goal_time_tolerance

        stream = self.worker.start_trajectory(plan)
        try:
            t0 = stream.started.result(timeout=5.0)
        except Exception as exc:  # noqa: BLE001 - reported to the client
            return R.INVALID_GOAL, f"the controller did not take the trajectory: {exc}"
        feedback = FollowJointTrajectory.Feedback(joint_names=list(ARM_JOINTS))
        last = t0
        give_up = t0 + plan.duration_s + settle + 5.0
        while True:
            state = self.worker.wait_state(after=last, timeout=0.5)
            if goal_handle.is_cancel_requested:
                self._freeze()
                return R.SUCCESSFUL, "cancelled"
            if not self.worker.connected:
                return R.PATH_TOLERANCE_VIOLATED, f"stopped following: {self.worker.link_error}"
            if stream.finished_sending.done() and stream.finished_sending.exception():
                return R.PATH_TOLERANCE_VIOLATED, str(stream.finished_sending.exception())
            if state is None:  # a slow poll (a retried request); the link is still up
                if time.monotonic() > give_up:
                    return R.GOAL_TOLERANCE_VIOLATED, "no joint state from the arm in time"
                continue
            if proto.STATUS_COLLISION in state.status[:5]:
                return R.PATH_TOLERANCE_VIOLATED, (
                    self.worker.collision_message or "collision: the controller stopped the arm"
                )
            last = state.stamp
            elapsed = state.stamp - t0
            desired = plan.desired_at(elapsed)
            actual = state.positions[:5]
            errors = [_angle_diff(a, d) for a, d in zip(actual, desired, strict=True)]
            feedback.header.stamp = self.get_clock().now().to_msg()
            feedback.desired = JointTrajectoryPoint(
                positions=desired, time_from_start=_duration(elapsed)
            )
            feedback.actual = JointTrajectoryPoint(
                positions=list(actual), time_from_start=_duration(elapsed)
            )
            feedback.error = JointTrajectoryPoint(
                positions=errors, time_from_start=_duration(elapsed)
            )
            goal_handle.publish_feedback(feedback)
            for j, tol in enumerate(path_tol):
                if tol > 0.0 and abs(errors[j]) > tol:
                    self._freeze()
                    return R.PATH_TOLERANCE_VIOLATED, (
                        f"{ARM_JOINTS[j]} is {abs(errors[j]):.4f} rad off the path "
                        f"(tolerance {tol:.4f})"
                    )
            if elapsed < plan.duration_s or state.status_stamp < t0 + plan.duration_s:
                continue
            final = plan.final_angles()
            off = [abs(_angle_diff(a, f)) for a, f in zip(actual, final, strict=True)]
            within = all(tol < 0.0 or o <= tol for o, tol in zip(off, goal_tol, strict=True))
            if within and all(s in DONE_STATUS for s in state.status[:5]):
                return R.SUCCESSFUL, ""
            if elapsed > plan.duration_s + settle:
                j = max(range(5), key=lambda k: off[k])
                return R.GOAL_TOLERANCE_VIOLATED, (
                    f"{ARM_JOINTS[j]} ended {off[j]:.4f} rad from the goal "
                    f"(status flags {state.status[:5]})"
                )

    def _tolerances(self, goal) -> tuple[list[float], list[float]]:
        goal_tol = [self.goal_tolerance] * 5
        path_tol = [0.0] * 5
        for tol in goal.goal_tolerance:
            if tol.name in ARM_JOINTS and tol.position != 0.0:
                goal_tol[ARM_JOINTS.index(tol.name)] = tol.position
        for tol in goal.path_tolerance:
            if tol.name in ARM_JOINTS and tol.position > 0.0:
                path_tol[ARM_JOINTS.index(tol.name)] = tol.position
        return goal_tol, path_tol

    def _freeze(self) -> None:
        try:
            self.worker.stop_motion().result(timeout=3.0)
        except Exception as exc:  # noqa: BLE001 - logged; the caller reports the stop
            self.get_logger().error(f"could not stop the arm: {exc}")

    # ------------------------------------------------------------------ gripper
    def _gripper_goal(self, goal: GripperCommand.Goal) -> GoalResponse:
        if self._gripper_active:
            self.get_logger().warning("gripper goal rejected: another gripper goal is running")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _execute_gripper(self, goal_handle) -> GripperCommand.Result:
        self._gripper_active = True
        try:
            with self._motion_lock, self.worker.busy():
                result, outcome = self._run_gripper(goal_handle)
        finally:
            self._gripper_active = False
        if outcome == "succeed":
            goal_handle.succeed()
        elif outcome == "canceled":
            goal_handle.canceled()
        else:
            self.get_logger().warning(f"gripper goal not done: {outcome}")
            goal_handle.abort()
        return result

    def _run_gripper(self, goal_handle) -> tuple[GripperCommand.Result, str]:
        result = GripperCommand.Result()
        target = goal_handle.request.command.position
        lo, hi = self.model.gripper_limits()
        if not (math.isfinite(target) and lo - 1e-6 <= target <= hi + 1e-6):
            return result, f"position {target} outside the gripper's range [{lo}, {hi}] rad"
        problem = self._ready_problem()
        if problem:
            return result, problem
        enc = int(round(self.model.gripper_angle_to_encoder(target)))
        try:
            self.worker.call(lambda client: client.gripper(enc))
        except (TransportError, proto.ControllerError, TimeoutError) as exc:
            return result, f"the controller did not take the gripper command: {exc}"
        start = time.monotonic()
        limit = abs(target - self.worker.state.positions[5]) / 0.719 + 3.0 * self.stall_time + 2.0
        last, last_pos, moved_at = start, None, start
        feedback = GripperCommand.Feedback()
        while True:
            state = self.worker.wait_state(after=last, timeout=0.5)
            if goal_handle.is_cancel_requested:
                self._hold_gripper()
                return result, "canceled"
            if not self.worker.connected:
                return result, f"lost the arm: {self.worker.link_error}"
            if state is None:  # a slow poll; the link is still up
                if time.monotonic() - start > limit:
                    return result, "no joint state from the arm in time"
                continue
            if state.status[5] == proto.STATUS_COLLISION:
                return result, self.worker.collision_message or "collision"
            last = state.stamp
            pos = state.positions[5]
            if last_pos is None or abs(pos - last_pos) > 1e-3:
                last_pos, moved_at = pos, state.stamp
            result.position = feedback.position = float(pos)
            reached = abs(pos - target) <= self.gripper_tolerance
            stalled = not reached and state.stamp - moved_at >= self.stall_time
            feedback.reached_goal, feedback.stalled = reached, stalled
            goal_handle.publish_feedback(feedback)
            if reached and state.status_stamp > start and state.status[5] == proto.STATUS_HOLDING:
                result.reached_goal = True
                return result, "succeed"
            if stalled and state.stamp - start > self.stall_time:
                result.stalled = True  # fingers stopped on something: a grasp, as on the ROS 1 arm
                return result, "succeed"
            if state.stamp - start > limit:
                return result, f"the gripper did not reach {target:.3f} rad (at {pos:.3f})"

    def _hold_gripper(self) -> None:
        try:
            self.worker.call(lambda client: client.hold_motor(6, client.read_positions()[5]))
        except Exception as exc:  # noqa: BLE001
            self.get_logger().error(f"could not stop the gripper: {exc}")

    # ------------------------------------------------------------------ services
    def _set_motors(self, request: SetMotors.Request, response: SetMotors.Response):
        def switch(client):
            if request.enable:
                client.hold_all(client.read_positions())
            else:
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

    def _reset_world(self, request: ResetWorld.Request, response: ResetWorld.Response):
        response.success = False
        response.message = RESET_MESSAGE
        self.get_logger().warning(RESET_MESSAGE)
        return response


def _angle_diff(a: float, b: float) -> float:
    return (a - b + math.pi) % (2.0 * math.pi) - math.pi


def main(args: list[str] | None = None) -> int:
    rclpy.init(args=args)
    try:
        node = KatanaDriverNode()
    except Exception as exc:  # noqa: BLE001 - a bad parameter or set-up: say why and exit
        rclpy.logging.get_logger("katana_driver_node").fatal(str(exc))
        rclpy.try_shutdown()
        return 1
    executor = MultiThreadedExecutor(num_threads=4)
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
