"""Algorithm 1 and the strategies: when they query, when they plan, and what they reach."""

import math

import numpy as np
import pytest
from katana_curiosity.core.abstract_world import AbstractBlocksWorld
from katana_curiosity.core.environment import Setting
from katana_curiosity.core.explorer import PLAN, Q1, QUERY, RANDOM, Explorer
from katana_curiosity.core.predictors import ALPHA, THETA_ABSTRACT, PredictorBank, QueryRule
from katana_curiosity.core.strategies import make_strategy


class TracingWorld:
    """Wraps a world and records, at every observation, what the bank then held unknown."""

    def __init__(self, world: AbstractBlocksWorld, bank: PredictorBank, shuffled: bool) -> None:
        self.world, self.bank, self.shuffled = world, bank, shuffled
        self.unknown_available: list[bool] = []
        self.unknown_at_observe: list[np.ndarray] = []
        self.rng = np.random.default_rng(0)

    def observe(self):
        setting = self.world.observe()
        if not self.shuffled:  # an explicit scan order, to exercise the generic Setting
            order = self.rng.permutation(len(setting))
            setting = Setting.from_pairs(setting.states[order], setting.actions[order])
            self.world._last = setting
        self.unknown_at_observe.append(self.bank.unknown.copy())
        self.unknown_available.append(bool(self.bank.unknown[setting.available].any()))
        return setting

    def execute(self, state, action, index=None):
        return self.world.execute(state, action, index)


def make(name: str, seed: int = 0, shuffled: bool = True):
    world = AbstractBlocksWorld(seed=seed)
    rule = QueryRule(ALPHA, THETA_ABSTRACT)
    bank = PredictorBank(world.learned_heights, world.features, rule, n_states=world.top + 1)
    tracing = TracingWorld(world, bank, shuffled)
    strategy = make_strategy(name, bank, world.top, seed=seed)
    return Explorer(tracing, bank, strategy), tracing, strategy


@pytest.mark.parametrize("name", ["q1", "q10"])
@pytest.mark.parametrize("shuffled", [True, False])
def test_q1_never_plans_while_an_unknown_instance_is_available(name, shuffled) -> None:
    explorer, tracing, _ = make(name, seed=3, shuffled=shuffled)
    modes = []
    for t in range(4000):
        step = explorer.step()
        modes.append(step.mode)
        if step.mode == PLAN:
            assert not tracing.unknown_available[t]
        else:
            assert step.mode == QUERY
            assert tracing.unknown_at_observe[t][step.state, step.action], "queried a known one"
    assert PLAN in modes and QUERY in modes


def test_generic_scan_queries_the_first_unknown_in_scan_order() -> None:
    explorer, tracing, _ = make("q1", seed=1, shuffled=False)
    for _ in range(200):
        step = explorer.step()
        setting = tracing.world._last
        if step.mode == QUERY and isinstance(setting, Setting):
            flags = tracing.unknown_at_observe[-1][setting.states, setting.actions]
            first = int(np.argmax(flags))
            assert (setting.states[first], setting.actions[first]) == (step.state, step.action)


def test_q10_replans_every_ten_observations_and_conf_every_step() -> None:
    explorer, _, strategy = make("q10", seed=2)
    for _ in range(95):
        explorer.step()
    assert strategy.planner.calls == math.ceil(95 / 10)
    explorer, _, strategy = make("conf", seed=2)
    modes = [explorer.step().mode for _ in range(50)]
    assert strategy.planner.calls == 50 and set(modes) == {PLAN}
    explorer, _, strategy = make("random", seed=2)
    assert {explorer.step().mode for _ in range(50)} == {RANDOM}


def test_unknown_strategy_name_lists_the_known_ones() -> None:
    world = AbstractBlocksWorld()
    bank = PredictorBank(world.learned_heights, world.features, n_states=world.top + 1)
    known = "conf, egreedy, lp, q1, q10, random, rmax, variance"
    with pytest.raises(ValueError, match=f"unknown strategy 'greedy': choose from {known}"):
        make_strategy("greedy", bank, world.top)


def test_alternatives_are_plain_python_ints() -> None:
    # ROS message fields abort the process on numpy integers: choices must be plain ints
    explorer, tracing, strategy = make("q1", seed=0)
    setting = tracing.observe()
    strategy.planner.solve()
    failed = strategy.planned(setting)
    alternatives = strategy.alternatives(setting, failed)
    assert alternatives
    assert all(type(c.state) is int and type(c.action) is int for c in alternatives)
    assert type(failed.state) is int and type(failed.action) is int


def test_planned_choice_is_constrained_to_the_pairs_the_setting_offers() -> None:

    world = AbstractBlocksWorld(seed=0)
    bank = PredictorBank(world.learned_heights, world.features, n_states=world.top + 1)
    strategy = Q1(bank, world.top)
    q = np.zeros((world.top + 1, world.n_actions))
    q[1, 20], q[1, 7], q[1, 3] = 0.9, 0.5, 0.4  # the best action at height 1 is 20
    q[2] = 0.1
    strategy.planner.q = q
    # the fovea found only actions 3 and 7 at height 1 (and one at height 2)
    setting = Setting.from_pairs(np.array([2, 1, 1, 0]), np.array([5, 3, 7, 0]))
    choice = strategy.planned(setting)
    assert (choice.state, choice.action, choice.index) == (1, 7, 2), "best offered, with index"
    ranked = strategy.alternatives(setting, choice)
    assert [(c.state, c.action, c.index) for c in ranked] == [(1, 3, 1), (2, 5, 0), (0, 0, 3)]
    # with every pair available (the abstract world) the choice is the unconstrained optimum
    full = world.observe()
    assert strategy.planned(full).action == int(np.argmax(q[strategy.planned(full).state]))
