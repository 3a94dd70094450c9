"""Joint trajectory and gripper controllers of the simulated arm. ROS-free.

Both produce, at every physics step, motor targets that move no faster than the joint speed
limits; the world feeds them to PyBullet's position motors. Goals are validated first and a bad
one is refused with the same error codes as control_msgs/FollowJointTrajectory.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from katana_description import models as m

SUCCESSFUL = 0
INVALID_GOAL = -1
INVALID_JOINTS = -2
PATH_TOLERANCE_VIOLATED = -4
GOAL_TOLERANCE_VIOLATED = -5

RUNNING = "running"
SUCCEEDED = "succeeded"
ABORTED = "aborted"
CANCELED = "canceled"



@dataclass
class TrajectoryGoal:
    joint_names: list[str]
    times: list[float]  # seconds from start, strictly increasing
    positions: list[list[float]]  # one row per point, in joint_names order
    velocities: list[list[float]] | None = None
    goal_tolerance: dict[str, float] = field(default_factory=dict)  # rad; missing: default
    path_tolerance: dict[str, float] = field(default_factory=dict)  # rad; missing: none
    goal_time_tolerance: float = 0.0  # s after the last point; 0: default


@dataclass
class Outcome:
    status: str = RUNNING
    error_code: int = SUCCESSFUL
    message: str = ""

    @property
    def done(self) -> bool:
        return self.status != RUNNING


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


def validate_trajectory(goal: TrajectoryGoal, current: dict[str, float],
                        speed_margin: float = 1.02) -> tuple[int, str]:
    """(SUCCESSFUL, '') or (error code, reason) for a trajectory goal on the arm joints."""
    names = list(goal.joint_names)
    if not names:
        return INVALID_JOINTS, "no joint names"
    unknown = [n for n in names if n not in m.ARM_JOINTS]
    if unknown:
        return INVALID_JOINTS, (
            f"unknown or non-arm joints {unknown}; arm joints: {list(m.ARM_JOINTS)}")
    if len(set(names)) != len(names):
        return INVALID_JOINTS, f"duplicate joint names {names}"
    if not goal.times:
        return INVALID_GOAL, "no trajectory points"
    if len(goal.positions) != len(goal.times):
        return INVALID_GOAL, "positions and times differ in length"
    prev_t = -math.inf
    for i, (t, row) in enumerate(zip(goal.times, goal.positions, strict=True)):
        if len(row) != len(names):
            return INVALID_GOAL, f"point {i} has {len(row)} positions for {len(names)} joints"
        if not math.isfinite(t) or t < 0.0:
            return INVALID_GOAL, f"point {i} has time_from_start {t}"
        if t <= prev_t:
            return INVALID_GOAL, f"point {i}: times must increase strictly"
        prev_t = t
        for n, v in zip(names, row, strict=True):
            if not math.isfinite(v):
                return INVALID_GOAL, f"point {i}: {n} is not finite ({v})"
            lo, hi = m.JOINT_LIMITS[n]
            if not lo - 1e-6 <= v <= hi + 1e-6:
                return INVALID_GOAL, f"point {i}: {n} = {v:.4f} outside [{lo}, {hi}]"
    if goal.velocities is not None:
        if len(goal.velocities) != len(goal.times) or any(
            len(r) != len(names) or not all(math.isfinite(v) for v in r) for r in goal.velocities
        ):
            return INVALID_GOAL, "velocities must be finite, one per joint per point, or empty"
    # Speeds: peak of each interpolating segment, the first from the current position (at rest).
    prev_t, prev_q = 0.0, [current[n] for n in names]
    prev_v = [0.0] * len(names)
    for i, (t, row) in enumerate(zip(goal.times, goal.positions, strict=True)):
        dt = t - prev_t
        vel = goal.velocities[i] if goal.velocities is not None else [0.0] * len(names)
        for j, n in enumerate(names):
            dq = abs(row[j] - prev_q[j])
            if dt <= 0.0:
                if dq > 0.05:
                    return INVALID_GOAL, f"point {i}: {n} would jump {dq:.3f} rad at time 0"
                continue
            peak = hermite_peak_speed(prev_q[j], row[j], prev_v[j], vel[j], dt)
            limit = m.JOINT_MAX_SPEED[n]
            if peak > limit * speed_margin:
                return INVALID_GOAL, (
                    f"segment to point {i}: {n} needs {peak:.3f} rad/s, limit {limit:.3f}"
                )
        prev_t, prev_q, prev_v = t, list(row), list(vel)
    for n, v in {**goal.goal_tolerance, **goal.path_tolerance}.items():
        if n not in names:
            return INVALID_JOINTS, f"tolerance for a joint not in the trajectory: {n}"
        if not math.isfinite(v):
            return INVALID_GOAL, f"tolerance of {n} is not finite"
    if not math.isfinite(goal.goal_time_tolerance) or goal.goal_time_tolerance < 0:
        return INVALID_GOAL, f"goal_time_tolerance {goal.goal_time_tolerance} must be >= 0"
    return SUCCESSFUL, ""


class TrajectoryFollower:
    """Interpolates a validated goal: cubic Hermite segments (zero velocity at points that give
    none), from the positions the joints had when the goal started."""

    def __init__(self, goal: TrajectoryGoal, start_time: float, start_q: Sequence[float],
                 default_goal_tolerance: float = 0.005, default_goal_time: float = 1.0) -> None:
        self.names = list(goal.joint_names)
        self.t0 = start_time
        self.times = np.concatenate([[0.0], np.asarray(goal.times, float)])
        self.q = np.vstack([np.asarray(start_q, float), np.asarray(goal.positions, float)])
        if goal.velocities is None:
            self.v = np.zeros_like(self.q)
        else:
            self.v = np.vstack([np.zeros(len(self.names)), np.asarray(goal.velocities, float)])
        if self.times[1] <= 0.0:  # first point at t=0: start there (validated to be close)
            self.times, self.q, self.v = self.times[1:], self.q[1:], self.v[1:]
        self._time_list = self.times.tolist()
        self.goal_tol = np.array(
            [goal.goal_tolerance.get(n, 0.0) or default_goal_tolerance for n in self.names]
        )
        self.goal_tol[self.goal_tol < 0] = np.inf
        self.path_tol = np.array([goal.path_tolerance.get(n, 0.0) for n in self.names])
        self.path_tol[self.path_tol <= 0] = np.inf
        self.goal_time = goal.goal_time_tolerance or default_goal_time
        self.outcome = Outcome()

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    @property
    def end_time(self) -> float:
        return self.t0 + self.duration

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Desired positions and velocities at absolute time t."""
        s = t - self.t0
        if s >= self.times[-1]:
            return self.q[-1].copy(), np.zeros(len(self.names))
        if s <= self.times[0]:
            return self.q[0].copy(), np.zeros(len(self.names))
        # bisect on a list: numpy's searchsorted releases the GIL, costly with busy threads
        i = bisect.bisect_right(self._time_list, s) - 1
        h = self._time_list[i + 1] - self._time_list[i]
        u = (s - self._time_list[i]) / h
        p0, p1, v0, v1 = self.q[i], self.q[i + 1], self.v[i] * h, self.v[i + 1] * h
        u2, u3 = u * u, u * u * u
        h00, h10, h01, h11 = 2 * u3 - 3 * u2 + 1, u3 - 2 * u2 + u, -2 * u3 + 3 * u2, u3 - u2
        pos = h00 * p0 + h10 * v0 + h01 * p1 + h11 * v1
        d00, d10, d01, d11 = 6 * u2 - 6 * u, 3 * u2 - 4 * u + 1, -6 * u2 + 6 * u, 3 * u2 - 2 * u
        vel = (d00 * p0 + d10 * v0 + d01 * p1 + d11 * v1) / h
        return pos, vel

    def check(self, t: float, actual: np.ndarray) -> Outcome:
        """Update the outcome from the measured positions at time t."""
        if self.outcome.done:
            return self.outcome
        desired, _ = self.sample(t)
        err = np.abs(actual - desired)
        bad = np.nonzero(err > self.path_tol)[0]
        if bad.size and t < self.end_time:
            j = int(bad[0])
            self.outcome = Outcome(ABORTED, PATH_TOLERANCE_VIOLATED,
                                   f"{self.names[j]} off the path by {err[j]:.4f} rad")
        elif t >= self.end_time:
            final_err = np.abs(actual - self.q[-1])
            if np.all(final_err <= self.goal_tol):
                self.outcome = Outcome(SUCCEEDED, SUCCESSFUL, "")
            elif t > self.end_time + self.goal_time:
                j = int(np.argmax(final_err - self.goal_tol))
                self.outcome = Outcome(
                    ABORTED, GOAL_TOLERANCE_VIOLATED,
                    f"{self.names[j]} stopped {final_err[j]:.4f} rad from its goal "
                    f"(tolerance {self.goal_tol[j]:.4f}) {self.goal_time:.2f} s after the end",
                )
        return self.outcome


@dataclass
class GripperOutcome:
    status: str = RUNNING
    position: float = 0.0
    effort: float = 0.0
    stalled: bool = False
    reached_goal: bool = False
    message: str = ""

    @property
    def done(self) -> bool:
        return self.status != RUNNING


class GripperController:
    """Moves both finger targets towards a goal at the finger speed limit. Done when the fingers
    reach the goal, or stall (stop short, e.g. on a block) once the target has got there."""

    def __init__(self, goal: float, effort: float, start_time: float, start_target: float,
                 tolerance: float = 0.01, stall_speed: float = 0.02, stall_time: float = 0.1,
                 timeout: float = 1.5) -> None:
        lo, hi = m.GRIPPER_CLOSED, m.GRIPPER_OPEN
        self.goal = min(hi, max(lo, goal))
        self.effort = effort
        self.t0 = start_time
        self.start = start_target
        self.speed = m.JOINT_MAX_SPEED["katana_r_finger_joint"]
        self.ramp_end = start_time + abs(self.goal - start_target) / self.speed
        self.tol, self.stall_speed, self.stall_time, self.timeout = (
            tolerance, stall_speed, stall_time, timeout
        )
        self._still_since: float | None = None
        self.outcome = GripperOutcome()

    def target(self, t: float) -> float:
        if t >= self.ramp_end:
            return self.goal
        step = self.speed * (t - self.t0)
        span = self.goal - self.start
        return self.start + math.copysign(min(step, abs(span)), span)

    def check(self, t: float, positions: Sequence[float],
              velocities: Sequence[float]) -> GripperOutcome:
        if self.outcome.done:
            return self.outcome
        pos = float(np.mean(positions))
        if all(abs(p - self.goal) <= self.tol for p in positions):
            self.outcome = GripperOutcome(SUCCEEDED, pos, self.effort, False, True, "")
            return self.outcome
        # Stalled: the fingers stay still while the target is already past them (a block).
        target = self.target(t)
        blocked = t >= self.ramp_end or abs(target - pos) > 0.05
        if blocked and all(abs(v) < self.stall_speed for v in velocities):
            if self._still_since is None:
                self._still_since = t
            elif t - self._still_since >= self.stall_time:
                self.outcome = GripperOutcome(SUCCEEDED, pos, self.effort, True, False,
                                              "fingers stalled before the goal")
        else:
            self._still_since = None
        if not self.outcome.done and t > self.ramp_end + self.timeout:
            self.outcome = GripperOutcome(SUCCEEDED, pos, self.effort, True, False,
                                          "fingers did not settle; reporting stalled")
        return self.outcome
