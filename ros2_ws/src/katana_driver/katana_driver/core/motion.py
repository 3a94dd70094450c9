"""Running one arm or gripper goal on the ArmWorker and judging it by the arm contract (ROS-free).

The node converts messages to katana_description.arm_contract goals and back; everything in
between is here: validation (the same rules as the simulation), planning, streaming, watching
the polled state, and the safety rule that an aborted or cancelled goal freezes the arm
(flush the move buffers, hold every motor) before its result is returned. Every wait is
bounded and ends at once when ``stop`` is set (the node is shutting down).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from katana_description import arm_contract as ac
from katana_description import gripper_contract as gc

from . import protocol as p
from .arm import ArmState, ArmWorker
from .encoders import ARM_JOINTS, EncoderModel
from .splines import TrajectoryError, plan_trajectory
from .transport import NoReply, TransportError

START_TIMEOUT_S = 5.0  # the controller takes the first segments within this
STALE_STATE_S = 5.0  # no new joint state for this long ends the goal
FREEZE_WAIT_S = 5.0  # after a lost link, wait this long for it to come back to freeze the arm
KEEP_KNOTS_MIN_TICKS = 5  # shortest segment when knots are kept (16-bit p3 bounds it at speed)


@dataclass
class TrajectoryFeedback:
    elapsed_s: float
    desired: list[float]
    actual: list[float]

    @property
    def error(self) -> list[float]:
        return [ac.joint_error(a, d) for a, d in zip(self.actual, self.desired, strict=True)]


def ready_problem(worker: ArmWorker) -> str:
    """Why goals cannot run now ('' when they can)."""
    if not worker.connected:
        return f"no connection to the Katana controller ({worker.link_error})"
    if worker.setup_problem:
        return worker.setup_problem
    if not worker.calibrated:
        return "the arm is not calibrated; restart the driver with calibrate_on_startup:=true"
    if worker.state is None:
        return "no joint state read from the arm yet"
    return ""


def freeze(worker: ArmWorker, stop: threading.Event) -> str:
    """Stop the arm where it is; '' when done, else why not (waits for a lost link, bounded)."""
    deadline = time.monotonic() + FREEZE_WAIT_S
    problem = ""
    while not stop.is_set():
        try:
            worker.stop_motion().result(timeout=FREEZE_WAIT_S)
            return ""
        except Exception as exc:  # noqa: BLE001 - reported with the goal's result
            problem = str(exc) or type(exc).__name__
        if time.monotonic() > deadline:
            break
        stop.wait(0.1)
    return f"could not freeze the arm ({problem or 'stopping'})"


def _ended(worker: ArmWorker, stop: threading.Event, outcome: ac.Outcome) -> ac.Outcome:
    problem = freeze(worker, stop)
    if problem:
        outcome.message = f"{outcome.message}; {problem}"
    return outcome


def run_trajectory(
    worker: ArmWorker,
    model: EncoderModel,
    contract: ac.ArmContract,
    goal: ac.TrajectoryGoal,
    cancelled: Callable[[], bool],
    feedback: Callable[[TrajectoryFeedback], None],
    stop: threading.Event,
) -> ac.Outcome:
    """Validate, plan, stream and watch one trajectory goal; the outcome says how it ended."""
    problem = ready_problem(worker)
    if problem:
        return ac.Outcome(ac.ABORTED, ac.INVALID_GOAL, problem)
    state = worker.state
    current = dict(zip(ARM_JOINTS, state.positions[:5], strict=True))
    verdict = ac.validate_trajectory(goal, current, contract)
    if not verdict.ok:
        return ac.Outcome(ac.ABORTED, verdict.error_code, verdict.error_string)
    full = ac.complete_trajectory(goal, current)
    try:
        plan = _plan(model, state.encoders, full, contract, worker)
    except TrajectoryError as exc:
        return ac.Outcome(ac.ABORTED, ac.INVALID_GOAL, str(exc))
    judge = ac.TrajectoryJudge(full, contract, fingers_start=state.positions[5])
    stream = worker.start_trajectory(plan)
    try:
        t0 = stream.started.result(timeout=START_TIMEOUT_S)
    except Exception as exc:  # noqa: BLE001 - reported to the client
        return _ended(worker, stop, judge.abort(
            ac.INVALID_GOAL, f"the controller did not take the trajectory: {exc}"))
    try:
        return _watch(worker, plan, stream, judge, t0, cancelled, feedback, stop)
    except BaseException:  # anything unexpected (a feedback failure): stop the arm, re-raise
        freeze(worker, stop)
        raise


def _watch(worker, plan, stream, judge, t0, cancelled, feedback, stop) -> ac.Outcome:
    last = t0
    while True:
        state = worker.wait_state(after=last, timeout=0.5)
        if stop.is_set():
            return _ended(worker, stop, judge.abort(
                ac.PATH_TOLERANCE_VIOLATED, "the driver is shutting down"))
        if cancelled():
            return _ended(worker, stop, judge.cancel())
        if not worker.connected:
            return _ended(worker, stop, judge.abort(
                ac.PATH_TOLERANCE_VIOLATED, f"stopped following: {worker.link_error}"))
        sending = stream.finished_sending
        if sending.done() and sending.exception() is not None:
            text = str(sending.exception())
            if "collision" in text.lower():  # a segment refused after a collision: say so
                worker.wait_state(after=time.monotonic(), timeout=0.5)
                text = worker.collision_message or text
            return _ended(worker, stop, judge.abort(ac.PATH_TOLERANCE_VIOLATED, text))
        if state is None:
            if time.monotonic() - last > STALE_STATE_S:
                return _ended(worker, stop, judge.abort(
                    ac.GOAL_TOLERANCE_VIOLATED, f"no joint state in {STALE_STATE_S} s"))
            continue
        last = state.stamp
        if p.STATUS_COLLISION in state.status[:5]:
            return _ended(worker, stop, judge.abort(ac.PATH_TOLERANCE_VIOLATED, (
                worker.collision_message or "collision: the controller stopped the arm")))
        outcome = _judge(judge, plan, stream, state, t0, feedback)
        if outcome.status == ac.SUCCEEDED:
            return outcome
        if outcome.done:
            return _ended(worker, stop, outcome)


def _plan(model: EncoderModel, encoders, goal: ac.TrajectoryGoal, contract: ac.ArmContract,
          worker: ArmWorker | None = None):
    """Spline segments for the goal, with the contract's speed margin and the worker's limit
    margin and speed and acceleration limits (the defaults without a worker). Knots closer
    than 0.2 s are merged into one segment, whose cubic can bulge past a limit the goal's own
    curve only touches: then every knot is kept instead."""
    args = (model, encoders, goal.times_s, goal.positions, goal.velocities)
    limits = {} if worker is None else {
        "limit_margin": worker.limit_margin,
        "accel_limits": worker.acceleration_limits[:5],
        "firmware_speed_limits": worker.speed_limits[:5],
    }
    try:
        return plan_trajectory(*args, speed_scale=contract.speed_margin, **limits)
    except TrajectoryError as exc:
        if "overshoot" not in str(exc):
            raise
        return plan_trajectory(*args, speed_scale=contract.speed_margin,
                               min_segment_ticks=KEEP_KNOTS_MIN_TICKS, **limits)


def _judge(judge, plan, stream, state: ArmState, t0: float, feedback) -> ac.Outcome:
    # Time on the controller's schedule: a segment that went in late shifts what follows.
    elapsed = state.stamp - t0 - stream.lag_s
    if not stream.finished_sending.done():
        elapsed = min(elapsed, plan.duration_s - 1e-3)  # not over before every segment is in
    desired = plan.desired_at(max(0.0, elapsed))
    actual = list(state.positions[:5])
    feedback(TrajectoryFeedback(elapsed, list(desired), actual))
    end = t0 + stream.lag_s + plan.duration_s
    at_rest = state.status_stamp >= end and all(s in p.REST_STATUSES for s in state.status[:5])
    return judge.check(elapsed, desired, actual, at_rest=at_rest, fingers=state.positions[5])


def run_gripper(
    worker: ArmWorker,
    model: EncoderModel,
    contract: ac.ArmContract,
    goal: gc.GripperGoal,
    arm_active: bool,
    cancelled: Callable[[], bool],
    feedback: Callable[[gc.GripperOutcome], None],
    stop: threading.Event,
) -> gc.GripperOutcome:
    """Validate, command and watch one gripper goal."""
    state = worker.state
    position = state.positions[5] if state is not None else 0.0
    verdict = gc.validate_gripper(goal, arm_active=arm_active)
    problem = verdict.error_string or ready_problem(worker)
    if problem:
        return gc.GripperOutcome(ac.ABORTED, position, 0.0, False, False, problem)
    judge = gc.GripperJudge(goal, position, contract)
    problem = _gripper_margin_problem(worker, model, judge.goal)
    if problem:
        return gc.GripperOutcome(ac.ABORTED, position, 0.0, False, False, problem)
    try:
        _send_gripper(worker, model, judge.goal, contract.gripper_tolerance_rad)
    except (TransportError, p.ControllerError, TimeoutError) as exc:
        return judge.end(ac.ABORTED, position, f"the controller did not take the command: {exc}")
    start = last = time.monotonic()
    while True:
        state = worker.wait_state(after=last, timeout=0.5)
        now = time.monotonic()
        if stop.is_set() or cancelled():
            _hold_gripper(worker)
            status = ac.ABORTED if stop.is_set() else ac.CANCELED
            return judge.end(status, position, "canceled" if status == ac.CANCELED else "stopping")
        if not worker.connected:
            return judge.end(ac.ABORTED, position, f"lost the arm: {worker.link_error}")
        if state is None:
            if now - last > STALE_STATE_S:
                _hold_gripper(worker)
                return judge.end(ac.ABORTED, position, "no joint state from the arm in time")
            continue
        last = state.stamp
        position = state.positions[5]
        if state.status[5] == p.STATUS_COLLISION:
            return judge.end(ac.ABORTED, position, worker.collision_message or "collision")
        outcome = judge.check(state.stamp - start, position, state.velocities[5],
                              at_rest=state.status[5] not in p.MOVING_STATUSES)
        feedback(outcome if outcome.done else gc.GripperOutcome(ac.RUNNING, position, judge.effort))
        if outcome.done:
            return outcome


def _gripper_margin_problem(worker: ArmWorker, model: EncoderModel, target: float) -> str:
    """Why the gripper target is refused ('' when it is not): within limit_margin_encoders of
    motor 6's encoder range."""
    enc = model.gripper_angle_to_encoder(target)
    lo, hi = model.safe_range(6, worker.limit_margin)
    if lo <= enc <= hi:
        return ""
    return (f"gripper position {target:.4f} rad is encoder {enc:.0f}, closer than "
            f"{worker.limit_margin} encoders (limit_margin_encoders) to the end of the gripper "
            f"motor's range; targets stay in [{lo}, {hi}]")


def _send_gripper(worker: ArmWorker, model: EncoderModel, target: float, tol: float) -> None:
    """Move the gripper, never twice: after a lost reply, motor 6 moving (or already there)
    means it was taken; holding elsewhere means it was not, and only then is it sent again."""
    enc = int(round(model.gripper_angle_to_encoder(target)))
    for _ in range(2):
        try:
            worker.call(lambda client: client.gripper(enc))
            return
        except NoReply:
            status = worker.call(lambda client: client.read_status())[5]
            here = model.gripper_encoder_to_angle(worker.call(lambda c: c.read_positions())[5])
            if status in p.MOVING_STATUSES or abs(here - target) <= tol:
                return
    raise TransportError("the gripper command got no reply, twice, and was not taken")


def _hold_gripper(worker: ArmWorker) -> None:
    try:
        worker.call(lambda client: client.hold_motor(6, client.read_positions()[5]))
    except Exception:  # noqa: BLE001 - the goal's result says it ended; the log says why
        pass
