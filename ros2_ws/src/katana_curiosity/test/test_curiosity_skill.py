"""The stacking skill: constructed models, hand-computed answers."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from katana_curiosity.core.planner import HeightMDP, value_iteration
from katana_curiosity.core.predictors import GAMMA
from katana_curiosity.core.skill import (
    REACH_MARGIN_M,
    LearnedModel,
    SkillWorld,
    StackingSkill,
    build_stack,
    choose_base,
)
from katana_manipulation.core.reach import place_reach_table

N_ACTIONS = 6

# A model that learned the robot's world as intuition has it: on a block, action 6 (all five
# points on the block below) stays, action 1 (no overlap) falls; the table is always stable.
GOOD = np.array(
    [
        [1.0, 1.0, 1.0, 1.0, 1.0, 1.0],
        [-0.9, -0.6, -0.2, 0.3, 0.7, 0.95],
        [-0.95, -0.7, -0.4, 0.1, 0.5, 0.9],
        [-0.95, -0.8, -0.5, -0.1, 0.3, 0.8],
    ]
)


def test_the_tricky_situation_starts_again_from_height_one():
    """Figure 14: a stack of two that offers only poor placements, and single blocks. The
    model predicts a block on the two-stack falls, so the skill builds on a single block."""
    skill = StackingSkill(LearnedModel.from_margins(GOOD), target_height=3)
    # the two-stack is skewed: its top offers only actions 2 and 3; single blocks offer all
    offered = [(0, 1), (2, 2), (2, 3)] + [(1, a) for a in range(1, 7)]
    choice = skill.choose(offered)
    assert (choice.state, choice.action) == (1, 6)
    # a squarely built two-stack is the better base
    assert (skill.choose(offered + [(2, 6)]).state, skill.choose(offered + [(2, 6)]).action) == (
        2,
        6,
    )


def test_planned_values_equal_value_iteration_on_the_same_mdp():
    skill = StackingSkill(LearnedModel.from_margins(GOOD), target_height=3)
    reference = value_iteration(HeightMDP(skill.mdp.transitions, skill.mdp.rewards, GAMMA))
    feasible = np.isfinite(skill.q)
    assert feasible[0].sum() == 1  # on the table only action 1
    assert not feasible[1, 4] and feasible[2].all()  # on one block never action 5
    # action 5 is not the best anywhere here, so leaving it out changes no other value
    np.testing.assert_allclose(skill.q[1:3][feasible[1:3]], reference[1:3][feasible[1:3]],
                               atol=1e-9)
    # by hand: from height 2 with action 6 the goal is reached with P = (1 + 0.9) / 2
    assert skill.q[2, 5] >= 0.95 - 1e-12 and skill.success[2, 5] == pytest.approx(0.95)


def test_the_skill_does_not_take_a_stack_apart_to_build_it_again():
    """Seen on the sim: two two-stacks built with action 4 offer only poor placements; the
    MDP valued a block on the table (a fresh start) above them, the block came off a
    two-stack, and the skill built it again, to its bound. The table is the last resort."""
    skill = StackingSkill(LearnedModel.from_margins(GOOD), target_height=3)
    two_two_stacks = [(0, 1), (2, 1), (2, 2)]
    assert skill.q[0, 0] > max(skill.q[2, 0], skill.q[2, 1])  # what the MDP alone prefers
    choice = skill.choose(two_two_stacks)
    assert (choice.state, choice.action) == (2, 2)
    assert skill.choose([(0, 1), (3, 6)]).state == 0  # nothing else below the goal
    # and in a world of such stacks it gets there or runs into falls, never a loop
    world = SkewedStacks(seed=3)
    result = build_stack(world, skill, max_placements=12)
    assert result.placements and all(p.choice.state > 0 for p in result.placements)


class SkewedStacks(SkillWorld):
    """Four blocks: two two-stacks whose tops offer actions 1 and 2 only, where a placement
    stays with probability 0.5; any fall leaves a two-stack and two singles."""

    def __init__(self, seed: int) -> None:
        self.stacks, self.rng = [2, 2], random.Random(seed)

    def offered(self):
        return [(0, 1)] + [(h, a) for h in sorted(set(self.stacks)) if h > 0
                           for a in ((1, 2) if h == 2 else range(1, N_ACTIONS + 1))]

    def highest_stack(self) -> int:
        return max(self.stacks)

    def place(self, state: int, action: int) -> int:
        if state == 0:
            self.stacks = [2, 1, 1]
            return 1
        if state == 2 and self.rng.random() < 0.5:
            self.stacks = [3, 1]
            return 1
        self.stacks = [2, 1, 1] if state == 2 else [2, 2]
        return 1 if state == 1 else -1


def test_nothing_offered_below_the_goal_gives_no_choice():
    skill = StackingSkill(LearnedModel.from_margins(GOOD), target_height=2)
    assert skill.choose([(2, 6), (3, 1)]) is None
    with pytest.raises(ValueError):
        StackingSkill(LearnedModel.from_margins(GOOD), target_height=0)


class BlocksOnTable(SkillWorld):
    """Four blocks; placements stay with the true probability; a fall topples the stack's top
    blocks to the table, as in section 3.1. Stacks offer every action (a square stack)."""

    def __init__(self, truth: np.ndarray, stacks: list[int], seed: int) -> None:
        self.truth, self.stacks, self.rng = truth, list(stacks), random.Random(seed)
        self.blocks = sum(stacks)

    def offered(self):
        pairs = [(0, 1)]
        for height in sorted(set(self.stacks)):
            pairs += [(height, a) for a in range(1, N_ACTIONS + 1)]
        return pairs

    def highest_stack(self) -> int:
        return max(self.stacks)

    def place(self, state: int, action: int) -> int:
        target = self.stacks.index(state) if state > 0 else None
        # the block to move: the top of the lowest other stack
        source = min(
            (i for i in range(len(self.stacks)) if i != target), key=lambda i: self.stacks[i]
        )
        self.stacks[source] -= 1
        if target is None:
            self.stacks.append(1)
            label = 1
        elif self.rng.random() < (1 + self.truth[state, action - 1]) / 2:
            self.stacks[target] += 1
            label = 1
        else:  # the placed block and the blocks above a random level topple to the table
            keep = self.rng.randint(1, state)
            self.stacks += [1] * (state - keep + 1)
            self.stacks[target] = keep
            label = -1
        self.stacks = [h for h in self.stacks if h > 0]
        assert sum(self.stacks) == self.blocks
        return label


def _success_rate(model: np.ndarray, trials: int = 60) -> float:
    skill = StackingSkill(LearnedModel.from_margins(model), target_height=3)
    wins = 0
    for seed in range(trials):
        world = BlocksOnTable(GOOD, [2, 1, 1] if seed % 2 else [1, 1, 1, 1], seed)
        wins += build_stack(world, skill, max_placements=8).reached
    return wins / trials


def test_a_learned_model_stacks_more_often_than_an_untrained_one():
    learned = _success_rate(GOOD)
    untrained = _success_rate(np.zeros_like(GOOD))
    assert learned > untrained + 0.2


def test_build_stack_is_bounded_and_counts_falls():
    skill = StackingSkill(LearnedModel.from_margins(GOOD), target_height=3)
    world = BlocksOnTable(-np.ones_like(GOOD), [1, 1, 1, 1], seed=0)  # everything falls
    result = build_stack(world, skill, max_placements=5)
    assert not result.reached and len(result.placements) == 5
    assert result.falls == 5 and result.reason == "placement bound reached"


# the sim's place reach per stack height, m, from the arm's kinematics (as skill_node takes it)
PLACE_REACH_M = tuple((b.min_m, b.max_m) for b in place_reach_table(3, 0.03))


def test_the_base_is_a_stack_the_arm_can_build_on():
    """Seen on the sim (reset seed 100): (1, 3) was offered on a block 0.276 m out and on one
    0.19 m out; the first in scan order made a two-stack whose top the fovea could reach only
    at its near edge, and with four blocks the skill had none left to start again."""
    far, near = (0.276, 0.031), (0.198, 0.031)
    assert choose_base([far, near], state=1, target_height=3, place_reach_m=PLACE_REACH_M) == 1
    # the placement that reaches the target: where it is does not matter
    assert choose_base([far, near], state=2, target_height=3, place_reach_m=PLACE_REACH_M) == 0
    # none within reach: the nearest to it (0.26 is 0.02 beyond, 0.29 is 0.05)
    assert choose_base([(0.29, 0.0), (0.0, 0.26)], 1, 4, PLACE_REACH_M) == 1
    with pytest.raises(ValueError):
        choose_base([], 1, 3, PLACE_REACH_M)


@given(st.lists(st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3)), min_size=1, max_size=6),
       st.integers(0, 2))
def test_the_base_lies_within_the_next_reach_whenever_one_does(xy, state):
    """Against the geometry: if any candidate's block would sit (with the margin) within the
    place reach of the height it makes, the chosen one does; the first such in order."""
    chosen = choose_base(xy, state, 4, PLACE_REACH_M)
    near, far = PLACE_REACH_M[state + 1]
    inside = [i for i, (x, y) in enumerate(xy)
              if near + REACH_MARGIN_M <= math.hypot(x, y) <= far - REACH_MARGIN_M]
    if inside:
        assert chosen == inside[0]
    else:
        radius = [math.hypot(x, y) for x, y in xy]
        gap = [max(near + REACH_MARGIN_M - r, r - far + REACH_MARGIN_M) for r in radius]
        assert gap[chosen] == pytest.approx(min(gap))
