"""The stacking skill (paper Figure 14): an externally imposed goal met with the learned model.

The goal is a stack of a target height. The skill plans on the MDP of section 2.4 built from
the learned predictors, P(s+1 | s, a) = (1 + margin) / 2, with a reward of 1 for reaching the
target height and no phantom rewards. One change to section 2.4: a fall ends the attempt (an
absorbing failure state) instead of being spread over the lower heights, because the stack the
skill is building is the one that topples, and the setting after a fall is observed anew
anyway. Planned values are then the discounted probability of building the target height
without a fall, which is the reasoning of the paper's Figure 14. In a setting it takes,
among the (height, action) pairs the setting offers, the one with the highest planned value, so
a block goes where the model predicts the best chance of reaching the goal soon. In the paper's
"tricky situation" (a stack of two that the model says will fall under another block, and single
blocks) that is a single block: it starts again from height 1. After every outcome the setting is
observed again and the choice made anew; the number of placements is bounded.

The model knows heights, not places, so where to make a chosen pair is the skill's own choice:
on a stack from which the arm can still build up (`choose_base`). On the sim, a two-stack
built near the edge of the reach offered only placements on its near edge, and with four
blocks the skill had none left to start again.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from .planner import HeightMDP, lspi, transition_model
from .predictors import GAMMA
from .robot_loop import feasible_actions


@dataclass(frozen=True)
class LearnedModel:
    """The margins w.x of the learned predictors, per height (row) and action (column).

    `slot` < 0 marks heights without a predictor (a placement there is taken to succeed), as in
    PredictorBank, so `transition_model` reads either."""

    margin: np.ndarray
    slot: np.ndarray

    @classmethod
    def from_margins(cls, margin: np.ndarray) -> LearnedModel:
        margin = np.asarray(margin, dtype=float)
        if margin.ndim != 2 or not np.isfinite(margin).all():
            raise ValueError("margins must be a finite (heights x actions) table")
        return cls(margin, np.arange(margin.shape[0]))

    @classmethod
    def from_bank(cls, bank) -> LearnedModel:
        return cls(np.array(bank.margin, dtype=float), np.array(bank.slot))

    @property
    def n_actions(self) -> int:
        return self.margin.shape[1]


@dataclass(frozen=True)
class SkillChoice:
    """A placement the skill makes: on a stack of `state` blocks, with `action` (1-based)."""

    state: int
    action: int
    predicted_success: float  # P(the stack grows by one) under the learned model
    value: float  # planned value: discounted probability of reaching the goal


class StackingSkill:
    """Plans once for a target height; `choose` picks the best offered placement."""

    def __init__(self, model: LearnedModel, target_height: int, gamma: float = GAMMA,
                 table_action: int = 1) -> None:
        if not 1 <= target_height <= model.margin.shape[0]:
            raise ValueError(
                f"target height must be in [1, {model.margin.shape[0]}], got {target_height}"
            )
        if not 0.0 <= gamma < 1.0:
            raise ValueError(f"gamma must be in [0, 1), got {gamma}")
        self.model, self.target, self.gamma = model, target_height, gamma
        top = target_height
        # P(s+1 | s, a) of section 2.4 from the learned margins; a fall goes to the absorbing
        # state `fail` (= top + 1) instead of being spread over the lower heights
        self.success = np.zeros((top + 2, model.n_actions))
        self.success[:top] = transition_model(model, top)[np.arange(top), :, np.arange(1, top + 1)]
        transitions = np.zeros((top + 2, model.n_actions, top + 2))
        for s in range(top):
            transitions[s, :, s + 1] = self.success[s]
            transitions[s, :, top + 1] = 1.0 - self.success[s]
        rewards = np.zeros((top + 2, model.n_actions))
        rewards[top - 1] = self.success[top - 1]  # 1 on the placement that reaches the target
        feasible = feasible_actions(top, model.n_actions, table_action)
        self.mdp = HeightMDP(transitions, rewards, gamma)
        self.q = lspi(self.mdp, feasible=feasible).q

    def choose(self, offered: Iterable[tuple[int, int]]) -> SkillChoice | None:
        """The offered (height, action) pair with the highest planned value (ties: the higher
        predicted success, then the higher stack); None when nothing offered is below the goal.

        The table is the last resort: a block put there starts a stack of one, which exists
        already while a single block lies on the table (then a height-1 pair is offered), so
        it is worth anything only when every block is in a stack, and then the block comes off
        one of them. The MDP values it as a fresh start and not as undoing a stack; on the sim
        that made the skill take two-stacks apart and build them again until its bound."""
        offered = [(int(s), int(a)) for s, a in offered
                   if 0 <= s < self.target and 1 <= a <= self.model.n_actions]
        if any(s > 0 and np.isfinite(self.q[s, a - 1]) for s, a in offered):
            offered = [(s, a) for s, a in offered if s > 0]
        best: SkillChoice | None = None
        for state, action in offered:
            value = float(self.q[state, action - 1])
            if not np.isfinite(value):
                continue
            choice = SkillChoice(state, action, float(self.success[state, action - 1]), value)
            if best is None or (value, choice.predicted_success, state) > (
                best.value,
                best.predicted_success,
                best.state,
            ):
                best = choice
        return best


#: how far inside the place reach of the next height a new stack top should sit: a quarter of a
#: block edge, ample for the placement error (p95 0.6 mm on the sim) and the fovea's grid step
REACH_MARGIN_M = 0.01


def reach_band(made: int, target_height: int,
               place_reach_m: Sequence[tuple[float, float]]) -> tuple[float, float] | None:
    """The (near, far) radius from the pan axis within which a stack of height `made` must stand
    for blocks to be placed on it at every height from `made` up to `target_height`: the
    narrowest of those heights' place reach bands; None when `made` is beyond the table."""
    if made >= len(place_reach_m):
        return None
    top = max(made, min(target_height, len(place_reach_m) - 1))
    bands = place_reach_m[made:top + 1]
    return max(b[0] for b in bands), min(b[1] for b in bands)


def outside_band_m(xy: tuple[float, float], band: tuple[float, float],
                   margin_m: float = 0.0) -> float:
    """How far (m) the point `xy` lies outside the radius band `band` shrunk by `margin_m` on
    both sides; 0 inside."""
    radius = math.hypot(*xy)
    near, far = band
    return max(near + margin_m - radius, radius - (far - margin_m), 0.0)


def choose_base(
    placements_xy: Sequence[tuple[float, float]],
    state: int,
    target_height: int,
    place_reach_m: Sequence[tuple[float, float]],
    margin_m: float = REACH_MARGIN_M,
) -> int:
    """Which of several placements realising the same (state, action) to make: the first whose
    block, once placed, lies within the place reach of the stack it makes (so the next block
    can go squarely onto it), else the one nearest that reach; the first when this placement
    reaches the target. `place_reach_m[h]` is the (near, far) radius from the pan axis of a
    placement on a stack of height h (katana_manipulation.core.reach.place_reach_table)."""
    if not placements_xy:
        raise ValueError("no placements to choose from")
    made = state + 1
    if made >= target_height or made >= len(place_reach_m):
        return 0
    band = place_reach_m[made]
    return min(range(len(placements_xy)),
               key=lambda i: (outside_band_m(placements_xy[i], band, margin_m), i))


@dataclass(frozen=True)
class SkillOutcome:
    choice: SkillChoice
    label: int
    height_after: int


@dataclass
class SkillResult:
    reached: bool
    height: int
    placements: list[SkillOutcome]
    reason: str

    @property
    def falls(self) -> int:
        return sum(1 for p in self.placements if p.label < 0)


class SkillWorld:
    """What the skill needs of a world: the offered pairs, a placement, the highest stack."""

    def offered(self) -> Sequence[tuple[int, int]]:
        raise NotImplementedError

    def place(self, state: int, action: int) -> int:
        """Place a block on a stack of `state` with `action`; return the label (+1 / -1), or
        0 when no placement was made (the arm lost the block on the way): the skill observes
        the setting again and chooses anew, within the same bound."""
        raise NotImplementedError

    def highest_stack(self) -> int:
        raise NotImplementedError


def build_stack(world: SkillWorld, skill: StackingSkill, max_placements: int,
                on_outcome: Callable[[SkillOutcome], None] | None = None) -> SkillResult:
    """Choose, place, observe, choose again, until the target height stands or the bound.
    `on_outcome` hears of every placement as it is judged (the action's feedback)."""
    if max_placements < 1:
        raise ValueError(f"max_placements must be >= 1, got {max_placements}")
    placements: list[SkillOutcome] = []
    for _ in range(max_placements):
        height = world.highest_stack()
        if height >= skill.target:
            return SkillResult(True, height, placements, "reached")
        choice = skill.choose(world.offered())
        if choice is None:
            return SkillResult(False, height, placements, "no placement offered")
        label = world.place(choice.state, choice.action)
        if label == 0:
            continue
        placements.append(SkillOutcome(choice, label, world.highest_stack()))
        if on_outcome is not None:
            on_outcome(placements[-1])
    height = world.highest_stack()
    reached = height >= skill.target
    return SkillResult(
        reached, height, placements, "reached" if reached else "placement bound reached"
    )
