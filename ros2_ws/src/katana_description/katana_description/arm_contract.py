"""The arm contract: how every backend (sim_node, katana_driver_node) answers arm goals.

ROS-free, so both nodes answer every goal the same way and the rules are tested without ROS.
Joint names, limits and speeds come from :mod:`katana_description.models`; error codes are
control_msgs/FollowJointTrajectory's, the action both backends serve.

API (stable; plain Python in, plain Python out):

- ``ArmContract(model="450_6m180", max_trajectory_s=60.0, default_goal_tolerance_rad=0.01,
  default_goal_time_tolerance_s=1.0, ...)``: the per-backend settings; ``ValueError`` when
  one is out of range. ``contract.limits`` and ``contract.max_speed`` give the joint facts;
  ``contract.target_limits`` the limits shrunk by ``limit_margin_enc`` encoders (where targets
  may lie) and ``contract.max_accel`` the acceleration limits (rad/s^2) from
  ``acceleration_limits`` (encoders per 10 ms tick squared, motors 1..5). The defaults are the
  driver's (katana_description.models: LIMIT_MARGIN_ENC 200, KNI_MAX_ACCELERATION 2).
- ``check_point_count(n_points) -> Verdict``: a goal of more than ``MAX_TRAJECTORY_POINTS``
  (1000) points is refused before its points are read.
- ``TrajectoryGoal(joint_names, times_s, positions, velocities=None, path_tolerance={},
  goal_tolerance={}, goal_time_tolerance_s=0.0, multi_dof_joints=())``: a
  FollowJointTrajectory goal; ``multi_dof_joints`` names the joints of its multi-DOF parts
  (``multi_dof_trajectory``, component tolerances), which the Katana does not have. Rows of
  ``positions``/``velocities`` are in ``joint_names`` order; a velocity row may be empty (all
  rows empty = the arm stops at every point). Tolerances are ``{name: rad}`` or a sequence of
  ``(name, rad)`` pairs (pairs let duplicates be detected): 0 = the contract's default,
  negative = no tolerance (control_msgs' meaning). A path or goal tolerance may also name a
  finger joint (``models.FINGER_JOINTS``): no gripper goal runs during an arm trajectory, and
  the fingers may move at most that far from where they were when the motion started, all
  along the motion (path) or where it ends (goal): how a pick-and-place watches a held block
  slip out while it carries it, and judges the grip where it is about to let go, both on the
  backend's own measurements. The smallest finger tolerance given of each kind counts, judged
  on the fingers' mean angle.
- ``validate_trajectory(goal, current, contract) -> Verdict``: ``Verdict(SUCCESSFUL, "")`` or
  the error code and a reason. ``current`` maps every arm joint to its measured angle (rad).
  Checked: names (arm joints only, no duplicates, no multi-DOF parts, INVALID_JOINTS; a partial goal
  names a subset and the other joints hold where they are), at least one point, finite times >= 0,
  strictly increasing, last point within ``max_trajectory_s``; finite positions within the model's
  limits (no wrapping: every Katana joint is a bounded revolute joint whose range is under 2 pi, so
  ``q + 2 pi`` is a different, unreachable, command), and every point after t = 0 within
  ``target_limits`` (a point at t = 0 stands for where the arm is, which may be closer to a limit;
  so may a joint the goal holds where it is at every point); velocities finite, one per joint or
  none, zero at the last point (both backends stop there); a point at t = 0 within
  ``START_JUMP_RAD`` of ``current``; the peak speed of every cubic Hermite segment (the first from
  ``current`` at rest) within the joint's limit times ``speed_margin``, and its peak acceleration
  within ``max_accel`` (no margin: the controller's limit); tolerances finite, for joints of the
  goal (or for the fingers), no duplicates; ``goal_time_tolerance_s`` finite
  and >= 0.
- ``complete_trajectory(goal, current) -> TrajectoryGoal``: the goal on all five arm joints in
  ``models.ARM_JOINTS`` order (joints a partial goal leaves out hold ``current``); velocities
  ``None`` when the goal gives none. Call it on a validated goal.
- ``TrajectoryJudge(goal, contract, fingers_start=None)``: judges completion of a validated,
  completed goal. ``judge.check(elapsed_s, desired, actual, at_rest=True, fingers=None) ->
  Outcome`` with ``elapsed_s`` from the start of motion and ``desired``/``actual`` in the
  goal's joint order. Path tolerances apply while ``elapsed_s < duration_s``
  (PATH_TOLERANCE_VIOLATED); the fingers' only when the backend passes their mean angle
  (``fingers``), measured from ``fingers_start`` or else from the first angle passed. After the
  last point the goal succeeds once every joint is within its goal tolerance and ``at_rest``
  (the backend's own "motion finished" signal), unless the fingers are then further than their
  goal tolerance from the start (GOAL_TOLERANCE_VIOLATED, FINGERS_MOVED); it fails with
  GOAL_TOLERANCE_VIOLATED after ``goal_time_s`` more. Errors are plain differences
  ``actual - desired`` (see wrapping above).
- ``Outcome``: ``status`` (RUNNING, SUCCEEDED, ABORTED, CANCELED), ``error_code``,
  ``message``; ``done``. ``hermite_peak_speed``, ``hermite_peak_accel`` and ``joint_error``
  are the helpers the rules use; ``fingers_moved(error_code, error_string)`` tells a stop by a
  finger tolerance, path or goal (its message begins with ``FINGERS_MOVED``), from other
  path and goal errors.

The gripper's goals follow the same contract in :mod:`katana_description.gripper_contract`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

from katana_description import models as m

# control_msgs/FollowJointTrajectory result codes (tests compare them with the built type's).
SUCCESSFUL = 0
INVALID_GOAL = -1
INVALID_JOINTS = -2
OLD_HEADER_TIMESTAMP = -3
PATH_TOLERANCE_VIOLATED = -4
GOAL_TOLERANCE_VIOLATED = -5

RUNNING = "running"
SUCCEEDED = "succeeded"
ABORTED = "aborted"
CANCELED = "canceled"

#: Slack on the joint limits for rounding (rad); a goal at the limit itself is valid.
LIMIT_SLACK_RAD = 1e-6
#: A point at time 0 stands for "where the arm is": it may differ by at most this (rad).
START_JUMP_RAD = 0.05
#: The last point's velocities must be zero to within this (rad/s).
REST_SPEED_RAD_S = 1e-9
Tolerances = Mapping[str, float] | Sequence[tuple[str, float]]


#: How the error string of a goal failed by a finger tolerance begins (both backends answer
#: with this contract's words, so a client tells that stop from a collision, which
#: control_msgs reports with the same PATH_TOLERANCE_VIOLATED, and that end from an arm joint
#: off its goal, GOAL_TOLERANCE_VIOLATED).
FINGERS_MOVED = "the fingers moved"


def fingers_moved(error_code: int, error_string: str) -> bool:
    """Whether a result is a failure by a path or goal tolerance on the fingers
    (FINGERS_MOVED)."""
    return (error_code in (PATH_TOLERANCE_VIOLATED, GOAL_TOLERANCE_VIOLATED)
            and error_string.startswith(FINGERS_MOVED))


class Verdict(NamedTuple):
    error_code: int
    error_string: str

    @property
    def ok(self) -> bool:
        return self.error_code == SUCCESSFUL


OK = Verdict(SUCCESSFUL, "")


@dataclass(frozen=True)
class ArmContract:
    """The rules' settings, one per backend node (from its parameters)."""

    model: str = m.DEFAULT_MODEL
    max_trajectory_s: float = 60.0
    default_goal_tolerance_rad: float = 0.01
    default_goal_time_tolerance_s: float = 1.0
    speed_margin: float = 1.02
    gripper_tolerance_rad: float = 0.01
    gripper_stall_speed: float = 0.02
    gripper_stall_time_s: float = 0.1
    gripper_timeout_s: float = 1.5
    limit_margin_enc: int = m.LIMIT_MARGIN_ENC
    acceleration_limits: tuple[float, ...] = (m.KNI_MAX_ACCELERATION,) * len(m.ARM_JOINTS)

    def __post_init__(self) -> None:
        m.get_model(self.model)  # ValueError naming the known models
        positive = {
            "max_trajectory_s": self.max_trajectory_s,
            "default_goal_tolerance_rad": self.default_goal_tolerance_rad,
            "gripper_tolerance_rad": self.gripper_tolerance_rad,
            "gripper_stall_speed": self.gripper_stall_speed,
            "gripper_stall_time_s": self.gripper_stall_time_s,
            "gripper_timeout_s": self.gripper_timeout_s,
        }
        for name, value in positive.items():
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be finite and > 0, got {value}")
        if not (
            math.isfinite(self.default_goal_time_tolerance_s)
            and self.default_goal_time_tolerance_s >= 0.0
        ):
            raise ValueError("default_goal_time_tolerance_s must be finite and >= 0")
        if not (math.isfinite(self.speed_margin) and 1.0 <= self.speed_margin <= 1.2):
            raise ValueError(f"speed_margin must be in [1, 1.2], got {self.speed_margin}")
        if not 0 <= self.limit_margin_enc <= 2000:
            raise ValueError(f"limit_margin_enc must be in [0, 2000], got {self.limit_margin_enc}")
        accel = tuple(self.acceleration_limits)
        if len(accel) != len(m.ARM_JOINTS) or not all(
            math.isfinite(a) and a > 0.0 for a in accel
        ):
            raise ValueError("acceleration_limits needs one finite value > 0 per arm joint, "
                             f"got {accel}")

    @property
    def limits(self) -> dict[str, tuple[float, float]]:
        return m.get_model(self.model).limits

    @property
    def max_speed(self) -> dict[str, float]:
        return m.JOINT_MAX_SPEED

    @property
    def target_limits(self) -> dict[str, tuple[float, float]]:
        """Where targets may lie: the limits shrunk by limit_margin_enc encoders."""
        return m.inner_limits(self.limits, self.limit_margin_enc)

    @property
    def max_accel(self) -> dict[str, float]:
        """rad/s^2 per arm joint, from acceleration_limits."""
        return {j: m.accel_limit_rad_s2(j, a)
                for j, a in zip(m.ARM_JOINTS, self.acceleration_limits, strict=True)}


@dataclass(frozen=True)
class TrajectoryGoal:
    joint_names: Sequence[str]
    times_s: Sequence[float]
    positions: Sequence[Sequence[float]]
    velocities: Sequence[Sequence[float]] | None = None
    path_tolerance: Tolerances = field(default_factory=dict)
    goal_tolerance: Tolerances = field(default_factory=dict)
    goal_time_tolerance_s: float = 0.0
    multi_dof_joints: Sequence[str] = ()


@dataclass
class GoalOutcome:
    """A judge's report on a goal: its `status`, RUNNING until the goal ends (`done`). The
    arm's Outcome and the gripper's GripperOutcome add what they report besides."""

    status: str = RUNNING

    @property
    def done(self) -> bool:
        return self.status != RUNNING


@dataclass
class Outcome(GoalOutcome):
    error_code: int = SUCCESSFUL
    message: str = ""


def hermite_peak_speed(p0: float, p1: float, v0: float, v1: float, h: float) -> float:
    """Largest |velocity| of the cubic Hermite segment from (p0, v0) to (p1, v1) over h seconds.
    Its velocity is a quadratic in time: the peak is at an end or at the vertex."""
    a = 6.0 * (p0 - p1) / h + 3.0 * (v0 + v1)  # v(s) = a s^2 + b s + v0, s = t / h in [0, 1]
    b = 6.0 * (p1 - p0) / h - 4.0 * v0 - 2.0 * v1
    candidates = [abs(v0), abs(v1)]
    if abs(a) > 1e-12:
        s = -b / (2.0 * a)
        if 0.0 < s < 1.0:
            candidates.append(abs(a * s * s + b * s + v0))
    return max(candidates)


def hermite_peak_accel(p0: float, p1: float, v0: float, v1: float, h: float) -> float:
    """Largest |acceleration| of the cubic Hermite segment from (p0, v0) to (p1, v1) over h
    seconds. Its acceleration is linear in time: the peak is at an end."""
    d = (p1 - p0) / h
    return max(abs(6.0 * d - 4.0 * v0 - 2.0 * v1), abs(-6.0 * d + 2.0 * v0 + 4.0 * v1)) / h


def joint_error(actual: float, desired: float) -> float:
    """actual - desired, unwrapped: Katana joints are bounded (range < 2 pi), not continuous."""
    return actual - desired


def _pairs(tolerances: Tolerances) -> list[tuple[str, float]]:
    if isinstance(tolerances, Mapping):
        return [(str(k), float(v)) for k, v in tolerances.items()]
    return [(str(k), float(v)) for k, v in tolerances]


def _check_tolerances(kind: str, tolerances: Tolerances, names: Sequence[str]) -> Verdict:
    seen: set[str] = set()
    for name, value in _pairs(tolerances):
        if name not in names and name not in m.FINGER_JOINTS:
            return Verdict(
                INVALID_JOINTS,
                (f"{kind} tolerance for {name!r}, which is not a joint of the goal "
                 f"{list(names)} or a finger joint {list(m.FINGER_JOINTS)}"),
            )
        if name in seen:
            return Verdict(INVALID_JOINTS, f"{kind} tolerance for {name} given twice")
        seen.add(name)
        if not math.isfinite(value):
            return Verdict(INVALID_GOAL, f"{kind} tolerance of {name} is not finite ({value})")
    return OK


#: The most points a trajectory goal may have. The executor's moves have a handful; the Katana
#: runs one spline segment per pair of points, each at least one 10 ms tick long, so a goal of
#: max_trajectory_s (60 s) could not use more than 6,000, and no planner here sends near 1,000.
MAX_TRAJECTORY_POINTS = 1000


def check_point_count(n_points: int) -> Verdict:
    """OK, or INVALID_GOAL for more than MAX_TRAJECTORY_POINTS points. Called with the length of
    the goal message's point list before any point is read or converted, so a goal of a
    hundred thousand points costs its deserialisation by rclpy and nothing more."""
    if n_points > MAX_TRAJECTORY_POINTS:
        return Verdict(INVALID_GOAL, f"the trajectory has {n_points} points; at most "
                       f"{MAX_TRAJECTORY_POINTS} are taken (MAX_TRAJECTORY_POINTS)")
    return OK


def validate_trajectory(
    goal: TrajectoryGoal, current: Mapping[str, float], contract: ArmContract
) -> Verdict:
    """OK, or the control_msgs error code and the reason the goal cannot be run."""
    names = list(goal.joint_names)
    if not names:
        return Verdict(INVALID_JOINTS, "no joint names")
    unknown = [n for n in names if n not in m.ARM_JOINTS]
    if unknown:
        return Verdict(
            INVALID_JOINTS,
            (f"unknown or non-arm joints {unknown}; arm joints: {list(m.ARM_JOINTS)}"),
        )
    if len(set(names)) != len(names):
        return Verdict(INVALID_JOINTS, f"duplicate joint names {names}")
    if goal.multi_dof_joints:
        return Verdict(
            INVALID_JOINTS,
            (f"multi-DOF joints {list(goal.multi_dof_joints)}: the Katana has none (leave "
             "multi_dof_trajectory and the component tolerances empty)"),
        )
    times = [float(t) for t in goal.times_s]
    if not times:
        return Verdict(INVALID_GOAL, "the trajectory has no points")
    if len(goal.positions) != len(times):
        return Verdict(
            INVALID_GOAL, (f"{len(goal.positions)} position rows for {len(times)} points")
        )
    limits, speeds, targets = contract.limits, contract.max_speed, contract.target_limits
    held = _held(names, goal.positions, current)
    prev_t = -math.inf
    for i, (t, row) in enumerate(zip(times, goal.positions, strict=True)):
        if not math.isfinite(t) or t < 0.0:
            return Verdict(INVALID_GOAL, f"point {i} has time_from_start {t} s; need finite >= 0")
        if t <= prev_t:
            return Verdict(
                INVALID_GOAL,
                (f"point {i}: time_from_start {t} s must be later than the previous {prev_t} s"),
            )
        prev_t = t
        if len(row) != len(names):
            return Verdict(
                INVALID_GOAL, (f"point {i} has {len(row)} positions for {len(names)} joints")
            )
        for n, q in zip(names, row, strict=True):
            if not math.isfinite(q):
                return Verdict(INVALID_GOAL, f"point {i}: {n} is not finite ({q})")
            lo, hi = limits[n]
            if not lo - LIMIT_SLACK_RAD <= q <= hi + LIMIT_SLACK_RAD:
                return Verdict(
                    INVALID_GOAL, (f"point {i}: {n} = {q:.6f} rad outside its limits [{lo}, {hi}]")
                )
            lo, hi = targets[n]
            if t > 0.0 and n not in held and not lo - LIMIT_SLACK_RAD <= q <= hi + LIMIT_SLACK_RAD:
                return Verdict(
                    INVALID_GOAL,
                    (f"point {i}: {n} = {q:.6f} rad is within {contract.limit_margin_enc} "
                     f"encoders of its limits; targets stay in [{lo:.6f}, {hi:.6f}]"),
                )
    if times[-1] > contract.max_trajectory_s:
        return Verdict(
            INVALID_GOAL,
            (
                f"the trajectory lasts {times[-1]:.6g} s, longer than max_trajectory_s "
                f"{contract.max_trajectory_s:g} s"
            ),
        )
    velocities = _velocity_rows(goal, len(names))
    if isinstance(velocities, Verdict):
        return velocities
    for n in names:
        if n not in current or not math.isfinite(current[n]):
            return Verdict(INVALID_GOAL, f"the arm's position of {n} is unknown")
    verdict = _check_speeds(names, times, goal.positions, velocities, current, contract, speeds)
    if not verdict.ok:
        return verdict
    for kind, tol in (("path", goal.path_tolerance), ("goal", goal.goal_tolerance)):
        verdict = _check_tolerances(kind, tol, names)
        if not verdict.ok:
            return verdict
    gtt = float(goal.goal_time_tolerance_s)
    if not (math.isfinite(gtt) and gtt >= 0.0):
        return Verdict(INVALID_GOAL, f"goal_time_tolerance {gtt} s must be finite and >= 0")
    return OK


def _held(names: Sequence[str], positions, current: Mapping[str, float]) -> set[str]:
    """The joints a goal keeps where they are at every point: a hold is no new target, so it
    may be anywhere within the limits (as the joints a partial goal leaves out)."""
    held = set()
    for j, n in enumerate(names):
        here = current.get(n)
        try:
            if here is not None and all(abs(float(row[j]) - float(here)) <= LIMIT_SLACK_RAD
                                        for row in positions):
                held.add(n)
        except (IndexError, TypeError, ValueError):
            continue
    return held


def _velocity_rows(goal: TrajectoryGoal, n_joints: int) -> list[list[float]] | None | Verdict:
    if goal.velocities is None:
        return None
    rows = [list(map(float, r)) for r in goal.velocities]
    if not rows or all(len(r) == 0 for r in rows):
        return None
    if len(rows) != len(goal.times_s) or any(len(r) != n_joints for r in rows):
        return Verdict(
            INVALID_GOAL, ("velocities must be given for every point, one per joint, or for none")
        )
    for i, r in enumerate(rows):
        if not all(math.isfinite(v) for v in r):
            return Verdict(INVALID_GOAL, f"point {i}: a velocity is not finite ({r})")
    if any(abs(v) > REST_SPEED_RAD_S for v in rows[-1]):
        return Verdict(
            INVALID_GOAL,
            (f"the last point's velocities {rows[-1]} must be zero: the arm stops there"),
        )
    return rows


def _check_speeds(names, times, positions, velocities, current, contract, speeds) -> Verdict:
    prev_t, prev_q, prev_v = 0.0, [float(current[n]) for n in names], [0.0] * len(names)
    accels = contract.max_accel
    for i, (t, row) in enumerate(zip(times, positions, strict=True)):
        vel = velocities[i] if velocities is not None else [0.0] * len(names)
        dt = t - prev_t
        for j, n in enumerate(names):
            if dt <= 0.0:  # a point at t = 0: where the arm is
                jump = abs(row[j] - prev_q[j])
                if jump > START_JUMP_RAD:
                    return Verdict(
                        INVALID_GOAL,
                        (
                            f"point {i} at time 0 puts {n} {jump:.4f} rad from where it is "
                            f"(at most {START_JUMP_RAD})"
                        ),
                    )
                continue
            peak = hermite_peak_speed(prev_q[j], row[j], prev_v[j], vel[j], dt)
            limit = speeds[n]
            if peak > limit * contract.speed_margin:
                return Verdict(
                    INVALID_GOAL,
                    (
                        f"segment to point {i}: {n} needs {peak:.3f} rad/s, above its limit "
                        f"{limit:.3f} rad/s; give the trajectory more time"
                    ),
                )
            accel = hermite_peak_accel(prev_q[j], row[j], prev_v[j], vel[j], dt)
            limit = accels[n]
            if accel > limit * (1.0 + 1e-6):
                return Verdict(
                    INVALID_GOAL,
                    (
                        f"segment to point {i}: {n} needs {accel:.3f} rad/s^2, above its "
                        f"acceleration limit {limit:.3f} rad/s^2; give the trajectory more time"
                    ),
                )
        prev_t, prev_q, prev_v = t, [float(q) for q in row], list(vel)
    return OK


def complete_trajectory(goal: TrajectoryGoal, current: Mapping[str, float]) -> TrajectoryGoal:
    """The goal on all five arm joints (ARM_JOINTS order); joints left out hold ``current``."""
    names = list(goal.joint_names)
    index = {n: i for i, n in enumerate(names)}

    def full(row: Sequence[float], hold: Mapping[str, float]) -> list[float]:
        return [float(row[index[n]]) if n in index else float(hold[n]) for n in m.ARM_JOINTS]

    zero = dict.fromkeys(m.ARM_JOINTS, 0.0)
    vel = goal.velocities
    rows = None
    if vel is not None and any(len(r) for r in vel):
        rows = [full(r, zero) for r in vel]
    return TrajectoryGoal(
        joint_names=list(m.ARM_JOINTS),
        times_s=[float(t) for t in goal.times_s],
        positions=[full(r, current) for r in goal.positions],
        velocities=rows,
        path_tolerance=dict(_pairs(goal.path_tolerance)),
        goal_tolerance=dict(_pairs(goal.goal_tolerance)),
        goal_time_tolerance_s=float(goal.goal_time_tolerance_s),
    )


class TrajectoryJudge:
    """Completion of one validated goal: path tolerances while it runs, goal tolerances after."""

    def __init__(self, goal: TrajectoryGoal, contract: ArmContract,
                 fingers_start: float | None = None) -> None:
        self.names = list(goal.joint_names)
        self.final = [float(q) for q in goal.positions[-1]]
        self.duration_s = float(goal.times_s[-1])
        goal_tol = dict(_pairs(goal.goal_tolerance))
        path_tol = dict(_pairs(goal.path_tolerance))
        self.goal_tol = [
            self._tol(goal_tol.get(n, 0.0), contract.default_goal_tolerance_rad) for n in self.names
        ]
        self.path_tol = [self._tol(path_tol.get(n, 0.0), math.inf) for n in self.names]
        self.finger_tol = self._finger_tol(path_tol)
        self.finger_goal_tol = self._finger_tol(goal_tol)
        self.fingers_start = None if fingers_start is None else float(fingers_start)
        self.goal_time_s = (
            float(goal.goal_time_tolerance_s) or contract.default_goal_time_tolerance_s
        )
        self.outcome = Outcome()

    @staticmethod
    def _tol(value: float, default: float) -> float:
        if value == 0.0:
            return default
        return math.inf if value < 0.0 else value

    @classmethod
    def _finger_tol(cls, tolerances: dict[str, float]) -> float:
        """The smallest finger tolerance given (0 or negative: none)."""
        return min((cls._tol(tolerances[n], math.inf) for n in m.FINGER_JOINTS
                    if n in tolerances), default=math.inf)

    def check(
        self,
        elapsed_s: float,
        desired: Sequence[float],
        actual: Sequence[float],
        at_rest: bool = True,
        fingers: float | None = None,
    ) -> Outcome:
        """Update and return the outcome from one measurement ``elapsed_s`` after the start;
        ``fingers``: the fingers' mean angle (rad), for a path tolerance on them."""
        if self.outcome.done:
            return self.outcome
        if fingers is not None and self.fingers_start is None:
            self.fingers_start = float(fingers)
        if elapsed_s < self.duration_s:
            moved = self._fingers_past(fingers, self.finger_tol, PATH_TOLERANCE_VIOLATED,
                                       "while the arm held them", "tolerance")
            if moved is not None:
                self.outcome = moved
                return self.outcome
            for j, n in enumerate(self.names):
                err = abs(joint_error(actual[j], desired[j]))
                if err > self.path_tol[j]:
                    self.outcome = Outcome(
                        ABORTED,
                        PATH_TOLERANCE_VIOLATED,
                        (f"{n} is {err:.4f} rad off the path (tolerance {self.path_tol[j]:.4f})"),
                    )
                    return self.outcome
            return self.outcome
        off = [abs(joint_error(a, f)) for a, f in zip(actual, self.final, strict=True)]
        if at_rest and all(o <= t for o, t in zip(off, self.goal_tol, strict=True)):
            moved = self._fingers_past(fingers, self.finger_goal_tol, GOAL_TOLERANCE_VIOLATED,
                                       "by the end of the motion", "goal tolerance")
            self.outcome = (moved if moved is not None
                            else Outcome(SUCCEEDED, SUCCESSFUL, ""))
        elif elapsed_s > self.duration_s + self.goal_time_s:
            j = max(range(len(off)), key=lambda k: off[k] - self.goal_tol[k])
            still = "" if at_rest else "; still moving"
            self.outcome = Outcome(
                ABORTED,
                GOAL_TOLERANCE_VIOLATED,
                (
                    f"{self.names[j]} ended {off[j]:.4f} rad from the goal (tolerance "
                    f"{self.goal_tol[j]:.4f}) {self.goal_time_s:.2f} s after the end{still}"
                ),
            )
        return self.outcome

    def _fingers_past(self, fingers: float | None, tolerance: float, error_code: int,
                      when: str, kind: str) -> Outcome | None:
        """The failure (FINGERS_MOVED) when the fingers are further than `tolerance` from
        where they started; None when they are not, or their angle is not known."""
        if fingers is None or self.fingers_start is None:
            return None
        moved = abs(float(fingers) - self.fingers_start)
        if moved <= tolerance:
            return None
        return Outcome(ABORTED, error_code,
                       (f"{FINGERS_MOVED} {moved:.4f} rad from {self.fingers_start:.4f} rad to "
                        f"{float(fingers):.4f} {when} ({kind} {tolerance:.4f})"))

    def cancel(self, message: str = "canceled") -> Outcome:
        if not self.outcome.done:
            self.outcome = Outcome(CANCELED, SUCCESSFUL, message)
        return self.outcome

    def abort(self, error_code: int, message: str) -> Outcome:
        """The backend ends the goal for its own reason (lost link, collision, timeout)."""
        if not self.outcome.done:
            self.outcome = Outcome(ABORTED, error_code, message)
        return self.outcome
