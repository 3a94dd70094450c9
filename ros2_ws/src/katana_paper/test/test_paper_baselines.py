"""The related-work baselines: each one's defining behaviour."""

import json
import warnings

import numpy as np
import pytest
from katana_curiosity.core.abstract_world import AbstractBlocksWorld
from katana_curiosity.core.environment import Setting
from katana_curiosity.core.explorer import PLAN, Q1, QUERY, RANDOM, Explorer
from katana_curiosity.core.planner import Planner, value_iteration
from katana_curiosity.core.predictors import ALPHA, THETA_ROBOT, PredictorBank, QueryRule
from katana_curiosity.core.strategies import STRATEGIES, make_strategy
from katana_curiosity.core.strategies_baselines import (
    EpsilonGreedy,
    LearningProgress,
    RMax,
    Variance,
)
from katana_paper.curiosity_cli import main


def make(strategy: str, seed: int = 0, rule: QueryRule | None = None):
    world = AbstractBlocksWorld(seed=seed)
    bank = PredictorBank(
        world.learned_heights, world.features, rule or QueryRule(), n_states=world.top + 1
    )
    return world, bank, make_strategy(strategy, bank, world.top, seed=seed)


def test_baselines_are_registered_by_name() -> None:
    for cls in (LearningProgress, Variance, RMax, EpsilonGreedy):
        assert STRATEGIES[cls.name] is cls
        _, _, strategy = make(cls.name)
        assert isinstance(strategy, cls)


def test_learning_progress_is_the_recent_decrease_of_the_prediction_error() -> None:
    _, bank, lp = make("lp")
    w = lp.window
    rng = np.random.default_rng(0)
    errors = {}
    # three pairs: errors falling, rising, and too few of them; fed through the bank's listener
    for (s, a), trend in {(1, 4): -1.0, (2, 7): 1.0}.items():
        history = np.clip(0.5 + trend * 0.04 * np.arange(3 * w) + rng.normal(0, 0.01, 3 * w), 0, 1)
        for e in history:
            margin = 1.0 - 2.0 * e  # with label +1 the error |1 - margin| / 2 is e
            lp._learned(s, a, 1.0, margin)
        errors[s, a] = history
    lp._learned(3, 2, 1.0, 0.0)
    reward = lp.progress(np.arange(bank.n_states))
    for (s, a), history in errors.items():
        older, recent = history[-2 * w : -w].mean(), history[-w:].mean()
        assert reward[s, a] == pytest.approx(max(older - recent, 0.0), abs=1e-12)
    assert reward[1, 4] > 0.1 and reward[2, 7] == 0.0
    assert reward[3, 2] == 1.0, "too few errors: still maximally promising"
    assert np.all(reward[0] == 0.0) and np.all(reward[bank.n_states - 1] == 0.0)


def test_learning_progress_hears_every_learned_example() -> None:
    world, bank, lp = make("lp", seed=1)
    explorer = Explorer(world, bank, lp)
    steps = [explorer.step() for _ in range(300)]
    learned = sum(1 for s in steps if s.state != 0)  # the table has no predictor
    assert lp.counts.sum() == learned
    assert {s.mode for s in steps} == {PLAN}


def test_variance_is_drawn_to_a_noisy_outcome_that_q1_knows() -> None:
    rule = QueryRule(ALPHA, THETA_ROBOT)
    world, bank, variance = make("variance", rule=rule)
    q1 = Q1(bank, world.top)
    for i in range(3000):  # action 3 at height 1 is a coin flip, and well known to be one
        bank.update(1, 3, 1.0 if i % 2 else -1.0)
    for _ in range(300):  # action 9 is stable, and well known to be
        bank.update(1, 9, 1.0)
    assert not bank.unknown[1, 3] and abs(bank.margin[1, 3]) < 0.05
    assert not bank.unknown[1, 9] and bank.unknown[1, 12]
    setting = Setting.from_pairs(np.array([0, 1, 1, 1]), np.array([0, 3, 9, 12]))
    assert q1.choose(setting, 0).action == 12, "Q1 queries the unknown instance"
    choice = variance.choose(setting, 0)
    assert (choice.state, choice.action, choice.mode) == (1, 3, PLAN)
    q = variance.planner.q
    assert q[1, 3] > q[1, 12] + 0.05, "not a near tie"
    expected = 1.0 - np.clip(bank.margin[1:8], -1, 1) ** 2
    np.testing.assert_allclose(variance.planner._mdp.rewards[1:8], expected)


def test_rmax_tries_every_available_pair_m_times_before_exploiting() -> None:
    world, bank, rmax = make("rmax", seed=2)
    counts = np.zeros_like(rmax.counts)
    queried = np.zeros_like(rmax.counts)
    explorer = Explorer(world, bank, rmax)
    modes = []
    for _ in range(2500):
        available = world._available(world._tops())
        before = counts.copy()
        step = explorer.step()
        modes.append(step.mode)
        if step.mode == PLAN:
            assert np.all(before[np.array(available)[1:]] >= rmax.tries), "planned too early"
        else:
            assert step.mode == QUERY and before[step.state, step.action] < rmax.tries
            queried[step.state, step.action] += 1
        if step.state != 0:
            counts[step.state, step.action] += 1
    np.testing.assert_array_equal(counts, rmax.counts)
    assert PLAN in modes and QUERY in modes
    assert queried.max() == rmax.tries, "no pair is queried more than m times"
    assert np.all(counts[1:3] >= rmax.tries), "every pair of the low heights was tried m times"


def test_egreedy_explores_randomly_with_probability_epsilon_and_otherwise_follows_the_plan():
    world, bank, egreedy = make("egreedy", seed=3)
    explorer = Explorer(world, bank, egreedy)
    n, randoms = 2000, 0
    for _ in range(n):
        available = world.observe().available  # what the explorer's step will observe too
        check = Planner(bank, world.top)
        q = check.solve()
        step = explorer.step()
        if step.mode == RANDOM:
            randoms += 1
        else:
            assert step.mode == PLAN
            assert q[step.state, step.action] == pytest.approx(q[available].max(), abs=1e-9)
    sd = np.sqrt(n * egreedy.epsilon * (1 - egreedy.epsilon))
    assert abs(randoms - n * egreedy.epsilon) < 4 * sd


def test_egreedy_plan_is_the_optimum_of_the_phantom_query_mdp() -> None:
    world, bank, egreedy = make("egreedy", seed=4)
    egreedy.epsilon = 0.0
    setting = world.observe()
    choice = egreedy.choose(setting, 0)
    q = value_iteration(egreedy.planner._mdp)
    values = q[setting.available].max(axis=1)
    assert q[choice.state].max() == pytest.approx(values.max(), abs=1e-7)


def test_paper_command_compares_the_baselines_in_summary_and_figure(tmp_path) -> None:
    out = tmp_path / "paper"
    strategies = ["q1", "conf", "random", "lp", "variance", "rmax"]
    argv = ["paper", "--experiments", "150", "--seeds", "2", "--strategies", ",".join(strategies)]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main([*argv, "--out", str(out)]) == 0
    # a figure's empty panel (no planned experiments in 150) draws no empty legend
    assert not [w for w in caught if "legend" in str(w.message)]
    summary = json.loads((out / "summary.json").read_text())
    assert list(summary["strategies"]) == strategies
    for m in strategies:
        assert (out / "runs" / f"{m}_seed1.csv").exists()
    for name in ("fig4", "fig5", "fig6", "fig7", "fig8", "fig9"):
        assert (out / f"{name}.png").read_bytes()[:4] == b"\x89PNG"
