"""Pick-and-place for the Katana: run a planned top-down pick and place through an abstract arm
port, judging the grasp as it goes. ROS-free.

The port offers three blocking, bounded calls (`move`, `grip`, `joint_positions`), so the same
sequence runs on the PyBullet world directly (tests), on the ROS arm and gripper actions
(pick_place_executor) and therefore on the real driver.

The plan comes from core.planner (everything planned and checked before the arm moves); the
goal, the settings, the port and the result codes are core.pick_place_types', all importable
from here as well. The grasp is judged from the finger angle: fingers that close well past the
block's width missed it; fingers that close further while carrying lost it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from katana_description import models as m
from katana_description.arm_contract import ArmContract

from katana_manipulation.core.pick_place_types import (
    ABORTED,
    ARM_DID_NOT_REACH,
    BLOCK_SLIPPED,
    DEFAULT_GEOMETRY,
    GRASP_MISSED,
    INVALID_GOAL,
    LEVEL_TOLERANCE_M,
    MIN_SEGMENT_TIME_S,
    PHASES,
    PICK_UNREACHABLE,
    PLACE_UNREACHABLE,
    SIM_MIN_SEGMENT_TIME_S,
    SUCCESS,
    TIMEOUT,
    UNREACHABLE,
    WORKSPACE_XY,
    ArmPort,
    GripResult,
    MoveResult,
    PickPlaceParams,
    PickPlaceRequest,
    PickPlaceResult,
    PlanError,
    ReachGeometry,
    Segment,
)
from katana_manipulation.core.planner import PickPlacePlanner

__all__ = [
    "ABORTED", "ARM_DID_NOT_REACH", "BLOCK_SLIPPED", "DEFAULT_GEOMETRY", "GRASP_MISSED",
    "INVALID_GOAL", "LEVEL_TOLERANCE_M", "MIN_SEGMENT_TIME_S", "PHASES", "PICK_UNREACHABLE",
    "PLACE_UNREACHABLE", "SIM_MIN_SEGMENT_TIME_S", "SUCCESS", "TIMEOUT", "UNREACHABLE",
    "WORKSPACE_XY", "ArmPort", "GripResult", "MoveResult", "PickPlaceParams", "PickPlaceRequest",
    "PickPlaceResult", "PlanError", "ReachGeometry", "Segment", "PickPlacePlanner", "ProgressFn",
    "execute_pick_place", "HOLD_TOLERANCE_RAD", "GRIP_THERE_RAD", "planning_start",
    "holds_where_sent",
]

ProgressFn = Callable[[str, float], None]


def execute_pick_place(req: PickPlaceRequest, port: ArmPort, planner: PickPlacePlanner,
                       feedback: ProgressFn | None = None,
                       cancelled: Callable[[], bool] | None = None) -> PickPlaceResult:
    """Plan, then run the segments through the port; never raises for arm trouble. The
    fingers open to the pregrasp opening (every plan's first segment) while the arm's moves
    are planned; the arm moves only once the whole plan is made and checked."""
    feedback = feedback or (lambda phase, progress: None)
    cancelled = cancelled or (lambda: False)
    joints = port.joint_positions()
    if joints is None:
        return PickPlaceResult(False, TIMEOUT, "no joint_states received: is the arm running?")
    current = planning_start([joints[n] for n in m.ARM_JOINTS], getattr(port, "commanded", None))
    try:
        opening = planner.pregrasp(req)
    except PlanError as exc:
        return PickPlaceResult(False, exc.code, str(exc))
    # Every plan opens the fingers first: they move while the arm's moves are planned, on a
    # thread of its own (planning reads only its arguments and the planner's settings, so the
    # plan is the one made before the fingers moved). Fingers still where the port's last grip
    # left them at that opening (the release of the pick before, of a block of the same size)
    # need no gripper goal.
    gripped = getattr(port, "gripped", None)
    there = (gripped is not None and abs(gripped - opening) <= GRIP_THERE_RAD
             and abs(_fingers(joints) - gripped) <= HOLD_TOLERANCE_RAD)
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="pick_place_planning") as pool:
        planning = pool.submit(planner.plan, req, current)
        g = None
        if not cancelled():
            feedback("approach", PHASES.index("approach") / len(PHASES))
            g = (GripResult(True, gripped, reached_goal=True) if there
                 else port.grip(opening, planner.p.grip_effort))
        try:
            segments = planning.result()
        except PlanError as exc:  # the fingers may have opened, in the air: nothing else moved
            return PickPlaceResult(False, exc.code, str(exc))
    if g is None:
        _recover(port, planner)
        return PickPlaceResult(False, ABORTED, "canceled", "approach")
    if not g.ok:
        code = TIMEOUT if g.timed_out else ARM_DID_NOT_REACH
        _recover(port, planner)
        return PickPlaceResult(False, code, f"approach: gripper: {g.message}", "approach")
    first = segments[0]
    if first.kind == "grip" and first.phase == "approach" and first.position == opening:
        segments = segments[1:]
    grip_at = released_at = math.nan
    for seg in segments:
        if cancelled():
            _recover(port, planner)
            return PickPlaceResult(False, ABORTED, "canceled", seg.phase)
        for phase in (seg.phase, *seg.also):
            feedback(phase, PHASES.index(phase) / len(PHASES))
        if seg.kind == "arm":
            # A move that holds the block is watched for a slip all along it, and judged where
            # it ends, where the block is about to be let go: both by the backend, on its own
            # measurements (a read of joint_states after the result could be one from before
            # the move's end, which arrives on another stream, in either order).
            watch, end = ((planner.p.carry_slip_tolerance, planner.p.slip_tolerance)
                          if seg.holding else (None, None))
            res = port.move(seg.points, seg.times, seg.velocities or None, watch, end)
            if not res.ok:
                _recover(port, planner)
                if res.fingers_moved:  # on the way (stopped there) or by the move's end
                    return PickPlaceResult(False, BLOCK_SLIPPED, f"{_phases(seg)}: "
                                           f"{res.message}: the block slipped out", seg.phase)
                code = TIMEOUT if res.timed_out else ARM_DID_NOT_REACH
                return PickPlaceResult(False, code, f"{_phases(seg)}: {res.message}", seg.phase)
        elif seg.kind == "grip":
            g = port.grip(seg.position, planner.p.grip_effort)
            if not g.ok:
                code = TIMEOUT if g.timed_out else ARM_DID_NOT_REACH
                _recover(port, planner)
                return PickPlaceResult(False, code, f"{seg.phase}: gripper: {g.message}", seg.phase)
            if seg.phase == "grasp":
                grip_at = g.position
            if seg.phase == "release":
                released_at = g.position
        elif seg.phase == "grasp":  # check the grip, on the gripper's own result
            expected = seg.position
            if not math.isfinite(grip_at) or grip_at < expected - planner.p.miss_tolerance:
                _recover(port, planner)
                return PickPlaceResult(
                    False, GRASP_MISSED,
                    f"fingers closed to {grip_at:.3f} rad; a block holds them near "
                    f"{expected:.3f}", seg.phase)
        else:  # check the release, on the gripper's own result
            if not released_at >= seg.position:  # stalled on the block: open once more
                g = port.grip(m.GRIPPER_OPEN, planner.p.grip_effort)
                released_at = g.position if g.ok else released_at
            if not released_at >= seg.position:
                # no recovery motion: leaving now would drag the block and its support
                return PickPlaceResult(
                    False, ARM_DID_NOT_REACH,
                    f"release: the fingers stayed at {released_at:.3f} rad, short of "
                    f"{seg.position:.3f}: the block is still held, the arm stays where it is",
                    seg.phase)
    feedback("park", 1.0)
    return PickPlaceResult(True, SUCCESS, "placed", "park")


#: the arm holds within this of where it was last sent (rad) for that pose to count as "here"
HOLD_TOLERANCE_RAD = 0.02
#: fingers this close to a goal (rad) are there: a gripper goal would end at once (the arm
#: contract's gripper_tolerance_rad)
GRIP_THERE_RAD = ArmContract.gripper_tolerance_rad


def _fingers(joints: dict[str, float]) -> float:
    return float(np.mean([joints[n] for n in m.FINGER_JOINTS]))


def _phases(seg: Segment) -> str:
    """The phases a (merged) move runs through, for messages: 'lift/carry/lower'."""
    return "/".join((seg.phase, *seg.also))


def holds_where_sent(joints: dict[str, float], commanded: Sequence[float] | None,
                     gripped: float | None) -> bool:
    """The arm within HOLD_TOLERANCE_RAD of where its last move was sent and the fingers of
    where its last gripper goal left them (a pose not known counts as held). What a task reads
    from the joints at its start (planning_start, and whether the fingers need a gripper goal)
    is then the same whenever those joints were read."""
    if commanded is not None and not all(
            abs(joints[n] - c) <= HOLD_TOLERANCE_RAD
            for n, c in zip(m.ARM_JOINTS, commanded, strict=True)):
        return False
    return gripped is None or abs(_fingers(joints) - gripped) <= HOLD_TOLERANCE_RAD


def planning_start(measured: Sequence[float], commanded: Sequence[float] | None) -> list[float]:
    """Where the next plan starts: the pose the arm was last sent to, while it holds there.

    A joint controller (the sim's, the driver's) starts a new trajectory from its own setpoint,
    the end of the last one, not from the measured angles, which wander by a few encoder ticks.
    Timing the plan from that setpoint makes the commanded motion, and so the whole run, the
    same whenever the arm is in the same state: measured angles sampled at a moment that depends
    on thread timing would change the segment times a little each run."""
    if commanded is not None and len(commanded) == len(measured) and all(
            abs(a - b) <= HOLD_TOLERANCE_RAD for a, b in zip(measured, commanded, strict=True)):
        return [float(v) for v in commanded]
    return [float(v) for v in measured]


def _recover(port: ArmPort, planner: PickPlacePlanner) -> None:
    """Best effort after a failure: open the gripper, go up and park (each call is bounded).
    The park is planned from joints read once they show the fingers where the opening left
    them (a port's `settled`, where it has one): joints from before the failure's stop, which
    the port may still hold when the gripper's result comes, would start it elsewhere."""
    try:
        opening = planner.p.park_gripper
        port.grip(m.GRIPPER_OPEN if opening is None else opening, 0.0)
        settled = getattr(port, "settled", None)
        if settled is not None:
            settled()
        joints = port.joint_positions()
        if joints is None:
            return
        for seg in planner.park_segments([joints[n] for n in m.ARM_JOINTS]):
            port.move(seg.points, seg.times, seg.velocities or None)
    except Exception:  # recovery must never mask the original failure
        return
