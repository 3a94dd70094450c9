"""sim_node: the PyBullet Katana world on ROS 2 (thin: physics and pacing live in katana_sim.core).

Publishes camera/image_raw + camera/camera_info (SENSOR_QOS), joint_states (JOINT_STATE_QOS),
/clock (CLOCK_QOS) and sim/ground_truth (STATE_QOS; for tests and evaluation only: nothing that
learns may read it), every stamp in simulated time. Serves arm_controller/follow_joint_trajectory
and gripper_controller/gripper_command (goals answered by the arm contract, as the driver does)
and ~/reset_world.

Pacing (katana_sim.core.pacing): with real_time_factor > 0 a stepping thread keeps simulated time
at that multiple of wall time and action callbacks wait for it; with 0 each action callback
lock-steps the physics of its own motion to the end, so runs are deterministic, while idle time
passes with the physics frozen; images are then made only with the arm out of the camera's view
(PhysicsSim.arm_in_view), so what they show never depends on thread timing. Outputs follow
simulated time (katana_sim.outputs)."""

from __future__ import annotations

import sys
import threading
import time

from control_msgs.action import FollowJointTrajectory, GripperCommand
from katana_common.diagnostics import Diagnostics
from katana_common.executor import MultiThreadedExecutor
from katana_common.health import ClockRatio, pace_health
from katana_common.messages import time_msg, trajectory_goal
from katana_common.node_runner import run_node
from katana_common.params import ParameterError, declare_parameters
from katana_description import arm_contract as ac
from katana_interfaces.srv import ResetWorld
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node

from katana_sim import messages as msgs
from katana_sim.core import ConfigError, PhysicsSim, pacing
from katana_sim.outputs import FAST_WALL_CAP_S, SimOutputs
from katana_sim.sim_params import PARAMS, cross_check, sim_config

#: fast mode renders only while the arm stands out of the camera's view (PhysicsSim.arm_in_view)
#: and has been idle this long (wall): long enough that the next goal of a task that is still
#: running usually comes first, so no image is spent on the pause between two of its motions.
#: What such an image shows does not depend on when it is made: nothing moves while the sim is
#: idle, and the fingers of an empty hand open and close clear of the blocks without physics
#: steps (PhysicsSim.step), so blocks that have just come to rest cannot creep meanwhile.
FAST_IMAGE_IDLE_S = 0.005
#: ... and an arm left standing in view (a task that ended where it failed) after this long
FAST_IMAGE_STANDING_S = 1.0
FEEDBACK_PERIOD_S = 0.2  # simulated seconds between action feedback messages


class SimNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("sim_node", **kwargs)
        self.params = declare_parameters(self, PARAMS, cross_check)
        try:
            cfg = sim_config(self.params)
        except ConfigError as exc:
            raise ParameterError(str(exc)) from None
        self.rtf = float(self.params["real_time_factor"])
        self.fast = self.rtf == 0.0
        self.world = PhysicsSim(cfg)
        self.lock = threading.RLock()
        self.stopping = threading.Event()
        self._stepped = threading.Condition()
        self._lockstepping = 0  # fast mode: motions being stepped by their callbacks (under lock)
        self.outputs = SimOutputs(self, self.world, self.stopping)
        self.params.on_change(self._on_params)
        group = ReentrantCallbackGroup()
        accept = lambda _g: GoalResponse.ACCEPT  # noqa: E731 - validated in execute, with a reason
        self.arm_server = ActionServer(
            self, FollowJointTrajectory, "arm_controller/follow_joint_trajectory",
            execute_callback=self._execute_trajectory, goal_callback=accept,
            cancel_callback=lambda _g: CancelResponse.ACCEPT, callback_group=group)
        self.gripper_server = ActionServer(
            self, GripperCommand, "gripper_controller/gripper_command",
            execute_callback=self._execute_gripper, goal_callback=accept,
            cancel_callback=lambda _g: CancelResponse.ACCEPT, callback_group=group)
        self.create_service(ResetWorld, "~/reset_world", self._reset, callback_group=group)
        self._pace_meter = ClockRatio(lambda: self.world.time)
        self.diagnostics = Diagnostics(self, {"physics": lambda: pace_health(
            self._pace_meter.ratio(), self.rtf, self.world.time)}, hardware_id="pybullet")
        self._thread = threading.Thread(target=self._pace, name="sim_pacing", daemon=True)
        self._thread.start()
        self.get_logger().info(
            f"sim ready: {cfg.num_blocks} blocks, physics {cfg.physics_rate:g} Hz, "
            f"real_time_factor {self.rtf:g}{' (lock-step)' if self.fast else ''}, "
            f"camera {cfg.camera.width}x{cfg.camera.height}")

    def _on_params(self, changed: dict) -> None:
        with self.lock:
            self.outputs.set_rates(changed)

    # ------------------------------------------------------------------ pacing and outputs
    def _pace(self) -> None:
        """Paced mode: step physics at rtf x wall time. Fast mode: let idle time pass."""
        world, dt = self.world, self.world.dt
        pacer = pacing.WallPacer(1.0 if self.fast else self.rtf)
        mine, idle_since = None, time.monotonic()
        fresh = False  # fast mode: the scene changed since the last image
        while not self.stopping.is_set():
            now = time.monotonic()
            if self._lockstepping:  # read without the lock, which the stepping callback wants
                idle_since = now
                self.stopping.wait(0.005)
                continue
            with self.lock:
                if self.fast and world.busy:  # a callback is starting its lock-step
                    idle_since = now
                else:
                    if world.time != mine:  # time moved under us: a motion or a reset
                        pacer.anchor(now, world.time)
                        idle_since = now if self.fast else idle_since
                        fresh = self.fast
                    steps = int(pacer.owed(now, world.time) / dt)
                    if steps > 0:
                        if self.fast:
                            world.advance_clock(steps * dt)
                        else:
                            world.step(min(steps, int(0.05 / dt) + 1))
                        images = not self.fast or self._may_image(now - idle_since)
                        # a changed scene is imaged at once: the image after a task is the
                        # first one the sim makes once the arm is out of view, not a period on
                        self.outputs.publish_due(images=images, image_now=images and fresh)
                        fresh = fresh and not images
                    mine = world.time
            if not self.fast:
                with self._stepped:
                    self._stepped.notify_all()
            self.stopping.wait(0.002 if not self.fast else 0.005)

    def _may_image(self, idle_s: float) -> bool:
        """Fast mode: whether an image may be made now (under the lock)."""
        return idle_s >= FAST_IMAGE_IDLE_S and (
            idle_s >= FAST_IMAGE_STANDING_S or not self.world.arm_in_view())

    def ground_truth_msg(self):  # the true scene as a BlockArray, for tests and benches
        with self.lock:
            return self.outputs.ground_truth_msg()

    # ------------------------------------------------------------------ motions
    def _run(self, handle, goal_handle, sim_budget_s: float, feedback) -> str:
        """Run a started motion to its end: lock-step (fast) or wait for the stepping thread."""
        def interrupted() -> str | None:
            if self.stopping.is_set():
                return pacing.STOPPED
            return pacing.CANCELED if goal_handle.is_cancel_requested else None

        next_feedback = [self.world.time, 0.0]  # simulated, wall

        def tick() -> None:
            with self.lock:  # reentrant: run_motion holds it already
                if self.world.time < next_feedback[0] or self.stopping.is_set():
                    return
                wall = time.monotonic()
                if self.fast and wall < next_feedback[1]:
                    return
                next_feedback[:] = (self.world.time + FEEDBACK_PERIOD_S,
                                    wall + FAST_WALL_CAP_S["feedback"])
                try:
                    goal_handle.publish_feedback(feedback())
                except Exception:  # the context went down under us (a signal)
                    if self.context.ok():
                        raise
                    self.stopping.set()

        if self.fast:
            def after_chunk() -> None:
                self.outputs.publish_due(images=False, force=handle.outcome.done)
                tick()
            with self.lock:
                self._lockstepping += 1
            try:
                return pacing.run_motion(self.world, handle, self.lock, sim_budget_s,
                                         interrupted, after_chunk)
            finally:
                with self.lock:
                    self._lockstepping -= 1
        return pacing.wait_motion(handle, self._stepped, sim_budget_s / self.rtf + 10.0,
                                  interrupted, tick)

    def _end(self, goal_handle, succeeded: bool, canceled: bool = False) -> None:
        """Report the goal's end; after shutdown there is nobody to tell (no traceback)."""
        try:
            (goal_handle.succeed if succeeded else
             goal_handle.canceled if canceled else goal_handle.abort)()
        except Exception:
            if not self.stopping.is_set():
                raise

    def _execute_trajectory(self, goal_handle):
        result = FollowJointTrajectory.Result()
        handle = None
        goal = trajectory_goal(goal_handle.request)
        if isinstance(goal, ac.Verdict):  # too many points, non-finite tolerance parts
            result.error_code, result.error_string = goal
        else:
            try:
                with self.lock:
                    handle = self.world.start_trajectory(goal)
            except (TypeError, ValueError) as exc:  # values no contract rule expected
                result.error_code, result.error_string = ac.INVALID_GOAL, f"bad goal: {exc}"
        if handle is None or handle.outcome.done:
            if handle is not None:
                result.error_code = handle.outcome.error_code
                result.error_string = handle.outcome.message
            self.get_logger().warning(f"trajectory refused: {result.error_string}")
            self._end(goal_handle, False)
            return result
        follower = handle.controller
        state = self._run(handle, goal_handle, follower.duration + follower.goal_time + 3.0,
                          lambda: msgs.trajectory_feedback(self.world, follower))
        if state == pacing.STOPPED:  # shutting down: the world may be closed already
            result.error_string = "sim_node is shutting down"
            self._end(goal_handle, False)
            return result
        if state != pacing.DONE:
            with self.lock:
                self.world.cancel_trajectory(state, only=handle)
            result.error_string = state
            if state == pacing.TIMEOUT:
                result.error_code = ac.GOAL_TOLERANCE_VIOLATED
                result.error_string = "no outcome in time"
            self._end(goal_handle, False, canceled=state == pacing.CANCELED)
            return result
        out = handle.outcome
        result.error_code, result.error_string = out.error_code, out.message
        self._end(goal_handle, out.status == ac.SUCCEEDED)
        return result

    def _execute_gripper(self, goal_handle):
        cmd = goal_handle.request.command
        result = GripperCommand.Result()
        with self.lock:
            handle = self.world.start_gripper(float(cmd.position), float(cmd.max_effort))
            result.position = float(self.world.joint_state()[0][5:].mean())
        if handle.outcome.done:
            self.get_logger().warning(f"gripper goal refused: {handle.outcome.message}")
            self._end(goal_handle, False)
            return result
        ctrl = handle.controller
        state = self._run(handle, goal_handle, ctrl.time_limit_s + 3.0,
                          lambda: msgs.gripper_feedback(self.world, ctrl))
        if state == pacing.STOPPED:  # shutting down: the world may be closed already
            self._end(goal_handle, False)
            return result
        with self.lock:
            if state != pacing.DONE:
                self.world.cancel_gripper(only=handle)
            out = handle.outcome
        result.position, result.effort = out.position, out.effort
        result.stalled, result.reached_goal = out.stalled, out.reached_goal
        self._end(goal_handle, state == pacing.DONE and out.status == ac.SUCCEEDED,
                  canceled=state == pacing.CANCELED)
        return result

    def _reset(self, request, response):
        try:
            with self.lock:
                self.world.cancel_trajectory("world reset")
                self.world.cancel_gripper()
                self.world.reset(None if request.seed < 0 else int(request.seed))
                # the new arm and scene at once, before the answer: a pick-and-place asked
                # for after it plans from the reset arm, not from a stale joint_states
                self.outputs.publish_due(images=False, force=True)
                seed = self.world.last_seed
                response.stamp = time_msg(self.world.time)  # no image before it shows it
        except (RuntimeError, ValueError, OverflowError) as exc:
            response.success, response.message = False, str(exc)
            return response
        response.success = True
        response.message = f"scattered {len(self.world.blocks)} blocks with seed {seed}"
        self.get_logger().info(response.message)
        return response

    def stop(self) -> None:
        """End the pacing thread and every motion wait at once (run_node calls this)."""
        self.stopping.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)

    def destroy_node(self) -> None:
        self.stop()
        with self.lock:  # a motion callback still running holds it between its steps
            self.world.close()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return run_node(SimNode, "sim_node", args,
                    executor_factory=lambda: MultiThreadedExecutor(num_threads=4))


if __name__ == "__main__":
    sys.exit(main())
