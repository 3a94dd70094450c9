"""katana_driver_node: the real Katana behind the same interfaces as sim_node.

A managed (lifecycle) node, as ROS hardware drivers are: configure opens the link and reads the
controller's identification, master version and state; activate runs the set-up (limits,
calibration when needed) and accepts goals; deactivate freezes the arm and refuses goals;
cleanup closes the link; shutdown (from any state) freezes and disconnects. A lost link or a
failed transition goes to ErrorProcessing, which freezes the arm (waiting a bounded time for
the link) and disconnects: the node lands in Unconfigured. With ``autostart`` (the default) the
node brings itself to active at start and again after an error (configure retried every
reconnect_period while the controller does not answer); a failed activation is not retried.

Publishes joint_states (polled at poll_rate once the arm is known calibrated, also while
inactive, for viewers; wall-time stamps of the poll) and arm_ready (std_msgs/Bool,
transient-local: true only while active, connected and calibrated: the graph waits for it);
serves arm_controller/follow_joint_trajectory, gripper_controller/gripper_command, ~/set_motors
and ~/reset_world (an operator must reset the blocks). Goals are judged by
katana_description.arm_contract, as in the simulation, and run by core.motion on the
core.arm.ArmWorker thread that owns the link; callbacks wait, so a MultiThreadedExecutor.
"""

from __future__ import annotations

import dataclasses
import sys
import threading
import time
from collections.abc import Callable

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
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.lifecycle import LifecycleNodeMixin, LifecycleState, TransitionCallbackReturn
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

RCLError = _rclpy.RCLError
SUCCESS = TransitionCallbackReturn.SUCCESS
FAILURE = TransitionCallbackReturn.FAILURE
ERROR = TransitionCallbackReturn.ERROR
#: lifecycle states in which the link is open (the primary states of lifecycle_msgs/State)
CONFIGURED = ("inactive", "active")
#: longest activation beyond calibration_timeout: limits, probe, back-off and inward moves, s
SETUP_SLACK_S = 40.0
#: requests of one connection, each with all its re-sends: echo, identification, master
#: version, a poll (positions and status) and an owed freeze (flush, positions, six holds)
CONNECT_REQUESTS = 13
#: period of the keeper: arm_ready, faults of the link, autostart's next step, s
KEEPER_PERIOD_S = 0.2


class KatanaDriverNode(LifecycleNodeMixin, Node):
    """Thin ROS layer over ArmWorker and core.motion: messages in, core calls, messages out;
    the lifecycle transitions call the worker (start, set_up, stop_motion, stop).

    rclpy's LifecycleNode, with the lifecycle services in a callback group of their own (a
    transition may calibrate for a minute: /diagnostics, in the default group, goes on)."""

    def __init__(self, node_name: str = "katana_driver_node", **kwargs) -> None:
        Node.__init__(self, node_name, **kwargs)
        self._lifecycle_group = MutuallyExclusiveCallbackGroup()
        LifecycleNodeMixin.__init__(self, callback_group=self._lifecycle_group)
        self.params = params = declare_parameters(self, PARAMS, cross_check)
        # the model parameter picks the KNI numbers (Katana type) and the gripper variant
        self.model = EncoderModel.for_model(params["model"])
        self.contract = self._contract()
        self._stop = threading.Event()  # the process ends: every wait ends
        self._active = False  # goals run only while active
        self._leaving = threading.Event()  # deactivating: running goals end, the arm frozen
        self._fault = ""  # why the link failed under a configured node ('' when none)
        self._losses_seen = 0
        self._keep_active = bool(params["autostart"])  # autostart: (re)activate by itself
        self._by_keeper = False  # a transition the keeper started (not a user's)
        self._next_try = 0.0
        self._last_problem = ""
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
            acceleration_limits=params["acceleration_limits"], auto_setup=False,
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
        self._guard_change_state()
        # the keeper shares the lifecycle services' (mutually exclusive) group, so a
        # transition it starts never runs beside one a service call started
        self.create_timer(KEEPER_PERIOD_S, self._keep, callback_group=self._lifecycle_group)
        self.diagnostics = Diagnostics(
            self, {"controller": lambda: driver_health(self.worker, self.lifecycle_state())},
            hardware_id=f"katana {params['model']}")
        self.get_logger().info(
            f"Katana {params['model']} over {self.worker.transport.name}; unconfigured"
            + (" (autostart: configuring and activating)" if self._keep_active else
               " (autostart false: waiting for configure and activate)"))

    def _guard_change_state(self) -> None:
        """A ChangeState request for a transition the current state does not offer raises in
        rclpy's service callback (and would end the executor): answer it with success false
        and say which transitions there are."""
        service = self._service_change_state
        change = service.callback

        def guarded(request, response):
            try:
                return change(request, response)
            except RCLError as exc:
                offered = ", ".join(t[1] for t in self._state_machine.available_transitions)
                self.get_logger().warning(
                    f"change_state refused: transition id {request.transition.id} "
                    f"'{request.transition.label}' is not offered in state "
                    f"{self.lifecycle_state()} (offered: {offered}) ({exc})")
                response.success = False
                return response

        service.callback = guarded

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

    @property
    def ready(self) -> bool:
        """Active (the transition done), connected, set up and calibrated: goals run."""
        return self._active and self.worker.ready and self.lifecycle_state() == "active"

    def _publish_ready(self) -> None:
        ready = self.ready
        if ready != self._ready:
            self._ready = ready
            self._ready_pub.publish(Bool(data=ready))
            self.get_logger().info("arm ready" if ready else "arm not ready")

    def lifecycle_state(self) -> str:
        """The lifecycle state's label: unconfigured, inactive, active, finalized, or a
        transition state (configuring, activating, ..., errorprocessing)."""
        return self._state_machine.current_state[1]

    def stop(self) -> None:
        """Freeze a moving arm, end every wait and the worker thread (run_node calls it, from
        any state; the state machine is left alone: a transition may be running)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._active = False
        if self.worker.connected:  # hold where it is (harmless when idle): stop any motion
            try:
                self.worker.stop_motion().result(timeout=0.8)
            except Exception:  # noqa: BLE001 - shutting down: the worker's close ends the link
                pass
        self.worker.stop(timeout=0.5)  # with the executor's 0.5 s: within a node's 2 s to end

    # ------------------------------------------------------------------ lifecycle
    def _transition(self, name: str, step: Callable[[], str]) -> TransitionCallbackReturn:
        """Run one transition's step: '' is success, text a failure (logged); an exception an
        error (ErrorProcessing follows)."""
        try:
            problem = step()
        except Exception as exc:  # noqa: BLE001 - rclpy would swallow it: say it, then error
            self.get_logger().error(f"{name} failed: {exc!r}")
            return ERROR
        if problem:
            if not (self._by_keeper and problem == self._last_problem):  # retries: once
                self.get_logger().error(f"{name} failed: {problem}")
            self._last_problem = problem
            return FAILURE
        self._last_problem = ""
        self.get_logger().info(f"{name}d: {self.lifecycle_goal(name)}")
        return SUCCESS

    @staticmethod
    def lifecycle_goal(name: str) -> str:
        return {"configure": "inactive (connected; goals refused until activated)",
                "activate": "active (goals accepted)", "deactivate": "inactive (arm frozen)",
                "cleanup": "unconfigured (disconnected)"}.get(name, name)

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition("configure", self._configure)

    def _configure(self) -> str:
        p = self.params
        self._fault = ""
        self._losses_seen = self.worker.link_losses
        self.worker.start()
        if self.worker.wait_connection(CONNECT_REQUESTS * p["timeout"] * (p["retries"] + 1)):
            if not self.worker.controller_refusal:
                return ""
            problem = self.worker.controller_refusal  # as KNI: this controller is not driven
        else:
            problem = self.worker.not_connected_message()
        self.worker.stop(timeout=1.0)
        return problem

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition("activate", self._activate)

    def _activate(self) -> str:
        self._leaving.clear()
        try:
            self.worker.set_up().result(
                timeout=self.params["calibration_timeout"] + SETUP_SLACK_S)
        except Exception as exc:  # noqa: BLE001 - the link or the set-up: reported
            return f"set-up did not run: {exc}"
        if not self.worker.ready:
            return (self.worker.setup_problem or motion.ready_problem(self.worker)
                    or "the arm is not ready")
        self._active = True  # arm_ready follows from the keeper, once the state is active
        return ""

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self._fault:  # the keeper's way into ErrorProcessing from active
            self._end_goals()
            self.get_logger().error(f"active -> error: {self._fault}")
            return ERROR
        return self._transition("deactivate", self._deactivate)

    def _end_goals(self) -> None:
        """Refuse new goals and end the running ones (each freezes the arm as it ends)."""
        self._active = False
        self._leaving.set()
        self._publish_ready()
        deadline = time.monotonic() + motion.FREEZE_WAIT_S + 1.0
        while (self._arm_active or self._gripper_active) and time.monotonic() < deadline:
            self._stop.wait(0.02)

    def _deactivate(self) -> str:
        self._end_goals()
        problem = motion.freeze(self.worker, self._stop)
        self._user_transition()
        return problem

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self._fault:  # the keeper's way into ErrorProcessing from inactive
            self.get_logger().error(f"inactive -> error: {self._fault}")
            return ERROR
        return self._transition("cleanup", self._cleanup)

    def _cleanup(self) -> str:
        self.worker.stop(timeout=1.0)
        self.worker.link_error = "disconnected: the driver is unconfigured (cleaned up)"
        self._user_transition()
        return ""

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._keep_active = False
        self._end_goals()
        problem = motion.freeze(self.worker, self._stop) if self.worker.connected else ""
        self.worker.stop(timeout=1.0)
        self.worker.link_error = "disconnected: the driver is shut down (finalized)"
        if problem:
            self.get_logger().error(f"shutdown: {problem}")
        self.get_logger().info("shut down: arm frozen and link closed")
        return SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """From any transition: end the goals, freeze the arm (waiting a bounded time for a
        lost link; else the freeze is sent first on the next connection), disconnect."""
        self._end_goals()
        problem = motion.freeze(self.worker, self._stop) if self.worker.running else ""
        self.worker.stop(timeout=1.0)
        why = self._fault or f"a failed transition from {state.label}"
        self.worker.link_error = f"disconnected after an error: {why}"
        if problem:
            self.worker.owe_freeze()
            self.get_logger().error(f"error processing: {problem}; the freeze is sent first on "
                                    "the next connection; use the emergency stop if it moves")
        else:
            self.get_logger().error(f"error processing ({why}): arm frozen, link closed")
        self._fault = ""
        self._next_try = time.monotonic() + self.worker.reconnect_period
        return SUCCESS  # -> unconfigured

    def _user_transition(self) -> None:
        """A deactivate or cleanup the keeper did not ask for: autostart stops keeping the
        driver active (a user took over); activating by hand resumes it."""
        if not self._by_keeper:
            self._keep_active = False

    def _keep(self) -> None:
        """The keeper: arm_ready, a failed link under a configured node (-> ErrorProcessing),
        and autostart's next transition."""
        self._publish_ready()
        if self._stop.is_set():
            return
        label = self.lifecycle_state()
        if label in CONFIGURED:
            losses = self.worker.link_losses
            if losses != self._losses_seen or not self.worker.running:
                self._losses_seen = losses
                self._fault = self.worker.link_error or "the link to the controller failed"
                (self.trigger_deactivate if label == "active" else self.trigger_cleanup)()
                return
        if label == "active" and self.params["autostart"]:
            self._keep_active = True  # activated (by hand too): kept active from here on
        if not self._keep_active or time.monotonic() < self._next_try:
            return
        self._by_keeper = True
        try:
            if label == "unconfigured" and self.trigger_configure() != SUCCESS:
                self._next_try = time.monotonic() + self.worker.reconnect_period
                return
            if self.lifecycle_state() == "inactive" and self.trigger_activate() != SUCCESS:
                self._keep_active = False  # a set-up problem: not retried (it may move the arm)
                self.get_logger().error("autostart: activation failed; fix the cause, then "
                                        "activate the driver by hand (lifecycle activate)")
        finally:
            self._by_keeper = False

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

    def _inactive_reason(self) -> str:
        """Why goals are refused now ('' while active)."""
        if self._active:
            return ""
        label = self.lifecycle_state()
        why = f"; {self.worker.not_connected_message()}" if not self.worker.connected else ""
        return (f"katana_driver_node is {label}, not active: goals run only while it is active "
                f"(lifecycle activate){why}")

    def _ended_by_deactivation(self, outcome, cancel_requested: bool):
        """A goal the deactivation ended is aborted with that reason (core.motion saw it as a
        cancel and froze the arm)."""
        if outcome.status == ac.CANCELED and not cancel_requested and self._leaving.is_set():
            message = "the driver was deactivated: goal ended, arm frozen"
            fields = {"status": ac.ABORTED, "message": message}
            if isinstance(outcome, ac.Outcome):
                fields["error_code"] = ac.PATH_TOLERANCE_VIOLATED
            return dataclasses.replace(outcome, **fields)
        return outcome

    def _execute_arm(self, goal_handle) -> FollowJointTrajectory.Result:
        goal = trajectory_goal(goal_handle.request)
        if not isinstance(goal, ac.Verdict) and self._inactive_reason():
            goal = ac.Verdict(ac.INVALID_GOAL, self._inactive_reason())
        busy = "" if isinstance(goal, ac.Verdict) else self._claim(arm=True)
        if isinstance(goal, ac.Verdict) or busy:
            refusal = goal if not busy else ac.Verdict(ac.INVALID_GOAL, busy)
            outcome = ac.Outcome(ac.ABORTED, refusal.error_code, refusal.error_string)
        else:
            try:
                with self.worker.busy():
                    outcome = motion.run_trajectory(
                        self.worker, self.model, self.contract, goal,
                        lambda: goal_handle.is_cancel_requested or self._leaving.is_set(),
                        lambda fb: self._feedback(goal_handle, msgs.trajectory_feedback(
                            fb, self.get_clock().now().to_msg())),
                        self._stop)
                outcome = self._ended_by_deactivation(outcome, goal_handle.is_cancel_requested)
            finally:
                self._arm_active = False
        return self._finish(goal_handle, outcome, msgs.trajectory_result(outcome), "trajectory")

    def _execute_gripper(self, goal_handle) -> GripperCommand.Result:
        goal = msgs.gripper_goal(goal_handle.request)
        verdict = gc.validate_gripper(goal)
        busy = self._inactive_reason() or (
            self._claim(arm=False) if verdict.ok else verdict.error_string)
        if busy:
            state = self.worker.state
            position = state.positions[5] if state is not None else 0.0
            outcome = gc.GripperOutcome(ac.ABORTED, position, message=busy)
        else:
            try:
                with self.worker.busy():
                    outcome = motion.run_gripper(
                        self.worker, self.model, self.contract, goal, False,
                        lambda: goal_handle.is_cancel_requested or self._leaving.is_set(),
                        lambda o: self._feedback(goal_handle, msgs.gripper_feedback(o)),
                        self._stop)
                outcome = self._ended_by_deactivation(outcome, goal_handle.is_cancel_requested)
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
