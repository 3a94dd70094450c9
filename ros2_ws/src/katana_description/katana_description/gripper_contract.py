"""The gripper contract: how every backend (sim_node, katana_driver_node) answers gripper
goals, beside the arm contract (:mod:`katana_description.arm_contract`: codes, settings,
statuses).

- ``GripperGoal(position, max_effort=0.0)`` (rad, N m; 0 = the backend's default effort);
  ``validate_gripper(goal, arm_active=False) -> Verdict``: finite position within
  [GRIPPER_CLOSED, GRIPPER_OPEN], finite max_effort >= 0, and no gripper goal while an arm
  goal is active (the hardware cannot run both at once; the simulation refuses it too).
  GripperCommand has no error code: a refusal is an aborted goal with this reason, and
  ``Verdict.error_code`` is INVALID_GOAL.
- ``GripperJudge(goal, start_position, contract)``: ``check(elapsed_s, position, speed,
  at_rest=True) -> GripperOutcome``. Reached (succeeded, reached_goal) within
  ``gripper_tolerance_rad`` once ``at_rest`` (the backend's "motor stopped"); stalled
  (succeeded, stalled: the fingers stopped on something, a grasp) when slower than
  ``gripper_stall_speed`` for ``gripper_stall_time_s`` while behind the ideal ramp to the goal
  at the finger speed limit; after that ramp plus ``gripper_timeout_s`` it reports stalled.
- ``GripperOutcome``: ``status`` (RUNNING, SUCCEEDED, ABORTED, CANCELED), ``position``,
  ``effort``, ``stalled``, ``reached_goal``, ``message``; ``done``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from katana_description import models as m
from katana_description.arm_contract import (
    INVALID_GOAL,
    LIMIT_SLACK_RAD,
    OK,
    SUCCEEDED,
    ArmContract,
    GoalOutcome,
    Verdict,
)

#: Fingers lagging the ideal ramp by more than this are "behind" (for the stall rule), rad.
GRIPPER_LAG_RAD = 0.05


@dataclass(frozen=True)
class GripperGoal:
    position: float
    max_effort: float = 0.0


@dataclass
class GripperOutcome(GoalOutcome):
    position: float = 0.0
    effort: float = 0.0
    stalled: bool = False
    reached_goal: bool = False
    message: str = ""


def validate_gripper(goal: GripperGoal, arm_active: bool = False) -> Verdict:
    """OK, or INVALID_GOAL and the reason a gripper goal is refused."""
    lo, hi = m.GRIPPER_CLOSED, m.GRIPPER_OPEN
    pos, effort = float(goal.position), float(goal.max_effort)
    if not math.isfinite(pos) or not lo - LIMIT_SLACK_RAD <= pos <= hi + LIMIT_SLACK_RAD:
        return Verdict(INVALID_GOAL, f"gripper position {pos} rad outside [{lo}, {hi}]")
    if not (math.isfinite(effort) and effort >= 0.0):
        return Verdict(INVALID_GOAL, f"max_effort {effort} N m must be finite and >= 0")
    if arm_active:
        return Verdict(INVALID_GOAL, "an arm trajectory is running; send the gripper goal after it")
    return OK


class GripperJudge:
    """Completion of one validated gripper goal (see the module docstring for the rules)."""

    def __init__(self, goal: GripperGoal, start_position: float, contract: ArmContract) -> None:
        self.goal = min(m.GRIPPER_OPEN, max(m.GRIPPER_CLOSED, float(goal.position)))
        self.effort = float(goal.max_effort)
        self.start = float(start_position)
        self.speed = m.JOINT_MAX_SPEED[m.FINGER_JOINTS[0]]
        self.ramp_s = abs(self.goal - self.start) / self.speed
        self.c = contract
        self._still_since: float | None = None
        self.outcome = GripperOutcome()

    @property
    def time_limit_s(self) -> float:
        """After this the judge has answered, whatever the fingers do."""
        return self.ramp_s + self.c.gripper_timeout_s

    def ideal(self, elapsed_s: float) -> float:
        """Where fingers at the finger speed limit would be ``elapsed_s`` after the start."""
        span = self.goal - self.start
        return self.start + math.copysign(min(self.speed * max(elapsed_s, 0.0), abs(span)), span)

    def check(self, elapsed_s: float, position: float, speed: float,
              at_rest: bool = True) -> GripperOutcome:
        """``at_rest``: the backend's own "motor stopped" signal; reached needs it."""
        if self.outcome.done:
            return self.outcome
        pos = float(position)
        if at_rest and abs(pos - self.goal) <= self.c.gripper_tolerance_rad:
            self.outcome = GripperOutcome(SUCCEEDED, pos, self.effort, False, True, "")
            return self.outcome
        behind = elapsed_s >= self.ramp_s or abs(self.ideal(elapsed_s) - pos) > GRIPPER_LAG_RAD
        if behind and abs(speed) < self.c.gripper_stall_speed:
            if self._still_since is None:
                self._still_since = elapsed_s
            elif elapsed_s - self._still_since >= self.c.gripper_stall_time_s:
                self.outcome = GripperOutcome(
                    SUCCEEDED, pos, self.effort, True, False, "fingers stalled before the goal"
                )
                return self.outcome
        else:
            self._still_since = None
        if elapsed_s > self.time_limit_s:
            self.outcome = GripperOutcome(
                SUCCEEDED,
                pos,
                self.effort,
                True,
                False,
                "fingers did not settle; reporting stalled",
            )
        return self.outcome

    def end(self, status: str, position: float, message: str) -> GripperOutcome:
        """The backend ends the goal itself (canceled, lost link, collision)."""
        if not self.outcome.done:
            self.outcome = GripperOutcome(
                status, float(position), self.effort, False, False, message
            )
        return self.outcome
