"""What a pick-and-place is made of: the goal, the planner's settings, the arm port, the planned
segments and the result codes. ROS-free; shared by the planner (planner.py), the sequence
(pick_place.py) and the reach (reach.py).

`PickPlaceParams` holds the one default of every planner setting: pick_place_executor declares
its parameters with these defaults, and the nodes that offer placements compute the arm's reach
from the same `ReachGeometry` (katana_manipulation.reach_params).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

from katana_description import models as m

# Result codes: the constants of katana_interfaces/action/PickAndPlace (a test checks that they
# agree). UNREACHABLE: a pose on the way (transit, park); the goal's own poses have their codes.
SUCCESS = 0
INVALID_GOAL = 1
UNREACHABLE = 2
GRASP_MISSED = 3
BLOCK_SLIPPED = 4
ARM_DID_NOT_REACH = 5
TIMEOUT = 6
ABORTED = 7
PICK_UNREACHABLE = 8
PLACE_UNREACHABLE = 9

#: the table top's extent, m (x min, x max, y min, y max): the workspace's floor
_TX, _TY = m.TABLE_CENTRE_XY
WORKSPACE_XY = (_TX - m.TABLE_SIZE[0] / 2, _TX + m.TABLE_SIZE[0] / 2,
                _TY - m.TABLE_SIZE[1] / 2, _TY + m.TABLE_SIZE[1] / 2)
#: a block centre may sit this far below its level's nominal height (a measured pose), m
LEVEL_TOLERANCE_M = 0.005

PHASES = ("approach", "descend", "grasp", "lift", "carry", "lower", "release", "retreat", "park")

#: shortest trajectory segment on the real arm, s: katana_driver merges spline knots closer
#: than 0.2 s (its splines.MIN_SEGMENT_TICKS, 20 ticks of 10 ms), so shorter segments can
#: speed the arm up between points. The default of the planner and of pick_place_executor.
MIN_SEGMENT_TIME_S = 0.2
#: the same on the simulation, whose controller follows any segment length exactly
#: (config/sim.yaml sets it for the executor; a test checks that they agree)
SIM_MIN_SEGMENT_TIME_S = 0.1


@dataclass
class PickPlaceRequest:
    pick: Sequence[float]  # block centre x, y, z (m)
    pick_yaw: float  # block yaw about +z (rad)
    block_size: Sequence[float]  # edges along the block's x, y, z (m)
    place: Sequence[float]  # where the block's centre goes
    place_yaw: float


@dataclass(frozen=True)
class ReachGeometry:
    """The settings of `PickPlaceParams` that decide where a top-down pick or place works
    (core.reach): the executor plans with them, so the reach must be computed with them too."""

    grasp_offset: float
    release_clearance: float
    min_approach_clearance: float
    approach_height: float
    approach_step: float


@dataclass
class PickPlaceParams:
    approach_height: float = 0.06  # above the grasp point, before descending
    # a descent starts on a grid of this step, down from approach_height, where the arm reaches
    approach_step: float = 0.004
    min_approach_clearance: float = 0.008  # pads above the block top, at the least
    grasp_offset: float = 0.003  # tool point above the block centre when grasping
    release_clearance: float = 0.002  # block bottom above its support when released
    pregrasp_margin: float = 0.024  # open this much wider than the block
    max_grasp_width: float = 0.085
    transit_radius: float = 0.12  # tool distance from the pan axis while panning
    # tool height while panning: the open pads (half a pad length below the tool point) clear a
    # stack of four by 1.7 cm, and a held block clears a stack of three
    transit_height: float = 0.15
    speed_fraction: float = 0.9  # of each joint's speed limit, at the peak of a move
    # of each joint's acceleration limit (the controller's, models.JOINT_MAX_ACCEL), at the
    # peak: the rest is for what the plan cannot know (the arm a few encoders off its last
    # target, the driver's rounding to whole encoders)
    accel_fraction: float = 0.85
    min_segment_time: float = MIN_SEGMENT_TIME_S
    # a stretch between waypoints gets points of its optimal motion about this far apart
    cruise_piece_s: float = 0.25
    transit_lift_rad: float = 0.2  # shoulder raised from the top-down transit pose
    clear_stack_blocks: int = 3  # leaving a place, clear stacks this high (with a held block)
    clearance: float = 0.005  # above a stack top, for the lowest pad or held-block point
    descend_points: int = 3  # intermediate points that keep descents nearly vertical
    miss_tolerance: float = 0.08  # rad: fingers closing this far past the block: missed
    # rad: fingers that end the carrying move this far from where they were at its start
    # (the arm contract's goal tolerance on them): slipped
    slip_tolerance: float = 0.05
    # rad: fingers closing this much further while the arm carries the block stop it (slipped);
    # lifting a block off its support squeezes it, the fingers closing by up to 0.06 rad in the
    # sim (bench_arm's trials), and a block gone lets them close by 0.17 rad or more
    carry_slip_tolerance: float = 0.1
    grip_effort: float = 0.0  # N m, 0: the gripper's default
    park_pose: Sequence[float] = field(default_factory=lambda: list(m.PARK_POSE))
    # finger angle to park with; None: keep the release opening (the next pick starts there, so
    # neither its first grip nor the last one of this pick costs a gripper motion)
    park_gripper: float | None = None

    @property
    def geometry(self) -> ReachGeometry:
        return ReachGeometry(grasp_offset=self.grasp_offset,
                             release_clearance=self.release_clearance,
                             min_approach_clearance=self.min_approach_clearance,
                             approach_height=self.approach_height,
                             approach_step=self.approach_step)


#: the planner's geometry with every default (what the reach assumes when given none)
DEFAULT_GEOMETRY = PickPlaceParams().geometry


@dataclass
class PickPlaceResult:
    success: bool
    code: int
    message: str
    phase: str = ""


@dataclass
class MoveResult:
    ok: bool
    message: str = ""
    timed_out: bool = False
    fingers_moved: bool = False  # failed by a finger tolerance (arm_contract.fingers_moved)


@dataclass
class GripResult:
    ok: bool
    position: float = math.nan
    stalled: bool = False
    reached_goal: bool = False
    message: str = ""
    timed_out: bool = False


class ArmPort(Protocol):
    """What the sequence needs from an arm. Every call returns within a bounded time. A port
    may also offer `commanded` and `gripped` (where its last move and gripper goal that
    succeeded ended) and `settled()` (a bounded wait until `joint_positions` shows the arm
    there: RosArmPort's), which the sequence uses where present."""

    def move(self, points: list[list[float]], times: list[float],
             velocities: list[list[float]] | None = None,
             finger_tolerance: float | None = None,
             finger_goal_tolerance: float | None = None) -> MoveResult:
        """Follow arm-joint waypoints (ARM_JOINTS order) at times from start (s), passing them
        at the given velocities (None: at rest). With a finger tolerance (rad) the backend
        stops the arm as soon as the fingers move further than that from where they were at
        the start (the arm contract's path tolerance on a finger joint): a held block slipping
        out lets them close. With a finger goal tolerance the move fails, the arm at its end,
        when the fingers end further than that from where they were at the start (the
        contract's goal tolerance on a finger joint): judged on the backend's own last
        measurement, not on joint_states that may arrive before or after the result."""
        ...

    def grip(self, position: float, effort: float) -> GripResult: ...

    def joint_positions(self) -> dict[str, float] | None: ...


@dataclass
class Segment:
    phase: str
    kind: str  # "arm" or "grip" or "check"
    points: list[list[float]] = field(default_factory=list)
    times: list[float] = field(default_factory=list)
    velocities: list[list[float]] = field(default_factory=list)
    position: float = 0.0
    start: list[float] = field(default_factory=list)  # arm pose the move starts from
    waypoints: list = field(default_factory=list)  # what `timed` made points/times of
    also: tuple[str, ...] = ()  # later phases this move runs through (merged moves)
    holding: bool = False  # an arm move carrying the block: the fingers are watched for a slip


class PlanError(Exception):
    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


def unreachable_code(what: str) -> int:
    """PICK_UNREACHABLE or PLACE_UNREACHABLE for the goal's own poses, UNREACHABLE otherwise."""
    if "pick" in what:
        return PICK_UNREACHABLE
    if "place" in what:
        return PLACE_UNREACHABLE
    return UNREACHABLE
