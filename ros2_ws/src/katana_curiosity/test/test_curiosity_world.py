"""The abstract blocks world of section 3.1: invariants, label model, toppling."""

import numpy as np
import pytest
from katana_curiosity.core.abstract_world import AbstractBlocksWorld
from katana_curiosity.core.environment import PlacementUnavailable
from scipy import stats


def check_invariants(world: AbstractBlocksWorld) -> None:
    q = world.q
    stacks = world.stacks()
    assert sorted(j for s in stacks for j in s) == list(range(world.n_blocks)), "blocks conserved"
    for stack in stacks:
        for level, j in enumerate(stack, start=1):
            assert abs(q[j]) == level
            assert (q[j] > 0) == (j == stack[-1]), "only the top of a stack is positive"
    # available heights, brute force from q alone (section 3.1)
    tops = q[q > 0]
    expected = [0] + sorted(set(tops.tolist())) if len(tops) >= 2 else [0]
    assert world.available_states() == expected


def test_invariants_hold_over_long_random_runs() -> None:
    for seed in range(5):
        world = AbstractBlocksWorld(seed=seed)
        rng = np.random.default_rng(seed)
        check_invariants(world)
        for _ in range(3000):
            setting = world.observe()
            s = int(rng.choice(setting.available))
            world.execute(s, int(rng.integers(world.n_actions)))
            check_invariants(world)


def test_paper_example_q_vector() -> None:
    world = AbstractBlocksWorld()
    world.arrange([[0, 1, 2, 3], [4, 6, 7, 5]])
    np.testing.assert_array_equal(world.q, [-1, -2, -3, 4, -1, 4, -2, -3])
    assert world.available_states() == [0, 4]


def test_true_models_are_sorted_by_stability_and_valid() -> None:
    world = AbstractBlocksWorld(seed=4)
    m = world.true_margin[1:]
    assert m.shape == (7, 21)
    assert np.all(np.diff(m, axis=1) >= 0), "feature index ascends with stability"
    assert np.all(np.abs(m) <= 1)
    assert len({tuple(row) for row in m}) == 7, "one different model per height"
    np.testing.assert_allclose(world.true_weights[1:] @ world.features.T, m)


@pytest.mark.parametrize("action", [0, 10, 20])
def test_label_frequencies_match_the_true_model(action: int) -> None:
    world = AbstractBlocksWorld(seed=9)
    n, stable = 4000, 0
    for _ in range(n):
        world.arrange([[j] for j in range(8)])
        stable += world.execute(1, action) == 1
    p = (1 + world.true_margin[1, action]) / 2
    assert stats.binomtest(stable, n, p).pvalue > 1e-4


def test_stable_placement_builds_the_stack() -> None:
    world = AbstractBlocksWorld(seed=0)
    world.true_margin[2] = 1.0  # certain success at height 2
    world.arrange([[0, 1], [2], [3], [4], [5], [6], [7]])
    assert world.execute(2, 5) == 1
    assert sorted(len(s) for s in world.stacks())[-1] == 3


def test_toppling_leaves_a_uniformly_chosen_height_and_flattens_the_rest() -> None:
    world = AbstractBlocksWorld(seed=2)
    world.true_margin[4] = -1.0  # certain fall at height 4
    heights = []
    for _ in range(3000):
        world.arrange([[0, 1, 2, 3], [4], [5], [6], [7]])
        assert world.execute(4, 0) == -1
        check_invariants(world)
        stack = next(s for s in world.stacks() if s[0] == 0)
        assert stack == [0, 1, 2, 3][: len(stack)], "blocks below the kept level are unchanged"
        heights.append(len(stack))
        assert all(len(s) == 1 for s in world.stacks() if s[0] != 0), "the rest lies flat"
    counts = np.bincount(heights, minlength=5)[1:]
    assert stats.chisquare(counts).pvalue > 1e-4, counts


def test_same_seed_same_world_and_events() -> None:
    def trace(seed: int) -> list:
        world = AbstractBlocksWorld(seed=seed)
        out = []
        for i in range(500):
            setting = world.observe()
            s = int(setting.available[i % len(setting.available)])
            out.append((s, world.execute(s, i % 21), tuple(world.q)))
        return out

    assert trace(5) == trace(5)
    assert trace(5) != trace(6)


def test_unavailable_placements_are_refused() -> None:
    world = AbstractBlocksWorld()
    with pytest.raises(PlacementUnavailable):
        world.execute(3, 0)
    with pytest.raises(PlacementUnavailable):
        world.execute(1, 21)
    world.arrange([list(range(8))])
    assert world.available_states() == [0]


@pytest.mark.parametrize("kwargs", [{"n_blocks": 1}, {"n_blocks": 100}, {"n_features": 0}])
def test_invalid_world_arguments(kwargs) -> None:
    with pytest.raises(ValueError):
        AbstractBlocksWorld(**kwargs)
