"""Joint trajectory and gripper controllers of the simulated arm. ROS-free.

Goals are validated and judged by the arm contract (katana_description.arm_contract), the same
rules the real arm's driver uses, so both answer every goal the same way. What is the sim's own
is how the motors are fed: at every physics step the controllers give position targets that
move no faster than the joint speed limits (a trajectory's cubic Hermite segments; the fingers'
ramp at their speed limit), and the world feeds them to PyBullet's position motors.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from katana_description.arm_contract import (
    ABORTED,
    CANCELED,
    ArmContract,
    Outcome,
    TrajectoryGoal,
    TrajectoryJudge,
)
from katana_description.gripper_contract import GripperGoal, GripperJudge, GripperOutcome


class TrajectoryFollower:
    """Interpolates a validated goal completed to all five arm joints: cubic Hermite segments
    (zero velocity at points that give none), from the motor targets at the start."""

    def __init__(self, goal: TrajectoryGoal, contract: ArmContract, start_time: float,
                 start_q: Sequence[float], fingers_start: float | None = None) -> None:
        self.names = list(goal.joint_names)
        self.t0 = start_time
        times = [0.0, *(float(t) for t in goal.times_s)]
        q = [list(map(float, start_q)), *(list(map(float, r)) for r in goal.positions)]
        zero = [0.0] * len(self.names)
        v = [zero, *(list(map(float, r)) for r in goal.velocities)] if goal.velocities else [
            zero for _ in q]
        if times[1] <= 0.0:  # first point at t=0: start there (validated to be close)
            times, q, v = times[1:], q[1:], v[1:]
        self._times, self._q, self._v = np.array(times), np.array(q), np.array(v)
        self.judge = TrajectoryJudge(goal, contract, fingers_start)

    @property
    def outcome(self) -> Outcome:
        return self.judge.outcome

    @property
    def duration(self) -> float:
        return float(self._times[-1])

    @property
    def goal_time(self) -> float:
        return self.judge.goal_time_s

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Desired positions and velocities at absolute time t."""
        pos, vel = self.sample_many(np.array([t], float))
        return pos[0], vel[0]

    def sample_many(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Desired positions and velocities (rows) at the absolute times t: one call per chunk
        of physics steps, since sampling each step alone cost the fast sim a third of its time
        in numpy calls on 5-vectors."""
        times = self._times
        if len(times) == 1:  # a single point at t=0: hold it
            n = len(np.atleast_1d(t))
            return np.tile(self._q[-1], (n, 1)), np.zeros((n, len(self.names)))
        s = np.clip(np.asarray(t, float) - self.t0, times[0], times[-1])
        i = np.clip(np.searchsorted(times, s, side="right") - 1, 0, len(times) - 2)
        h = (times[i + 1] - times[i])[:, None]
        u = (s - times[i])[:, None] / h
        p0, p1, v0, v1 = self._q[i], self._q[i + 1], self._v[i] * h, self._v[i + 1] * h
        u2, u3 = u * u, u * u * u
        pos = (2 * u3 - 3 * u2 + 1) * p0 + (u3 - 2 * u2 + u) * v0 + (3 * u2 - 2 * u3) * p1 + (
            u3 - u2) * v1
        vel = ((6 * u2 - 6 * u) * p0 + (3 * u2 - 4 * u + 1) * v0 + (6 * u - 6 * u2) * p1
               + (3 * u2 - 2 * u) * v1) / h
        ends = (s <= times[0]) | (s >= times[-1])  # held still before the start and after the end
        vel[ends] = 0.0
        return pos, vel

    def check(self, t: float, actual: np.ndarray, at_rest: bool,
              desired: np.ndarray | None = None, fingers: float | None = None) -> Outcome:
        """Judge a measurement at t; `desired` is sample(t) when the caller has it already;
        `fingers` the fingers' mean angle, which the trajectory holds."""
        if desired is None:
            desired, _ = self.sample(t)
        return self.judge.check(t - self.t0, desired.tolist(), list(actual), at_rest, fingers)


class GripperController:
    """Moves both finger targets towards a goal at the finger speed limit; the contract's
    GripperJudge says when it has reached the goal or stalled on a block."""

    def __init__(self, goal: GripperGoal, contract: ArmContract, start_time: float,
                 start_position: float) -> None:
        self.judge = GripperJudge(goal, start_position, contract)
        self.effort = float(goal.max_effort)
        self.t0 = start_time

    @property
    def outcome(self) -> GripperOutcome:
        return self.judge.outcome

    @property
    def time_limit_s(self) -> float:
        return self.judge.time_limit_s

    def target(self, t: float) -> float:
        return self.judge.ideal(t - self.t0)

    def check(self, t: float, positions: Sequence[float],
              velocities: Sequence[float]) -> GripperOutcome:
        pos = float(np.mean(positions))
        speed = max(abs(float(v)) for v in velocities)
        return self.judge.check(t - self.t0, pos, speed)

    def cancel(self, position: float, message: str = "canceled") -> GripperOutcome:
        return self.judge.end(CANCELED, position, message)


def refused(code: int, why: str) -> Outcome:
    """The outcome of a goal refused before it started."""
    return Outcome(ABORTED, code, why)


def rest(velocities: Sequence[float], speed_rad_s: float = 0.05) -> bool:
    """The arm's own 'motion finished' signal: every joint slower than speed_rad_s."""
    return all(abs(v) < speed_rad_s for v in velocities) and not any(
        math.isnan(v) for v in velocities)
