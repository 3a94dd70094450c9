"""The compiled fast path against the NumPy reference: same generator, same trajectories."""

import random

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_curiosity.core import fastpath, fastpath_kernels
from katana_curiosity.core.explorer import Explorer
from katana_curiosity.core.predictors import GAMMA
from katana_paper.experiments import FAST_STRATEGY_NAMES, RunConfig, build_run, run


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32), n=st.integers(1, 2**31), draws=st.integers(1, 40))
def test_generator_matches_cpython_random_bit_for_bit(seed: int, n: int, draws: int) -> None:
    reference = random.Random(seed)
    mt, pos = fastpath._mt_from(random.Random(seed))
    for i in range(draws):
        assert fastpath_kernels._randbelow(mt, pos, n) == reference.randrange(n)
        assert fastpath_kernels._random(mt, pos) == reference.random()
        width = 1 + i % 7  # the world's randint(1, state) for a toppling stack
        assert 1 + fastpath_kernels._randbelow(mt, pos, width) == reference.randint(1, width)
    # after the draws both generators are in the same state
    copy = random.Random()
    fastpath._mt_to(copy, mt, pos)
    assert copy.getstate() == reference.getstate()


def test_generator_survives_the_twist_of_its_624_word_state() -> None:
    reference = random.Random(7)
    mt, pos = fastpath._mt_from(random.Random(7))
    got = [fastpath_kernels._randbelow(mt, pos, 1000) for _ in range(2000)]
    assert got == [reference.randrange(1000) for _ in range(2000)]


def _compare_banks(fast_bank, ref_bank) -> None:
    np.testing.assert_allclose(fast_bank.w, ref_bank.w, rtol=0, atol=1e-9)
    np.testing.assert_allclose(fast_bank.a_inv, ref_bank.a_inv, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(fast_bank.examples, ref_bank.examples)
    np.testing.assert_array_equal(fast_bank.unknown, ref_bank.unknown)
    np.testing.assert_allclose(fast_bank.margin, ref_bank.margin, rtol=0, atol=1e-9)
    np.testing.assert_allclose(fast_bank.chi, ref_bank.chi, rtol=0, atol=1e-9)


@pytest.mark.parametrize("strategy", sorted(fastpath.FAST_STRATEGIES))
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fast_path_reproduces_the_reference_experiment_by_experiment(strategy: str, seed: int):
    """Queries, labels, modes and weights agree at checkpoints, across uneven chunks."""
    n = 1500
    config = RunConfig(strategy=strategy, seed=seed, experiments=n)
    ref_world, ref_bank, ref_strategy = build_run(config)
    explorer = Explorer(ref_world, ref_bank, ref_strategy)
    world, bank, agent = build_run(config)
    fast = fastpath.FastRun(strategy, world, bank, agent.rng, config.gamma, n)
    done = 0
    for chunk in (1, 16, 83, 400, 1000):
        fast.advance(chunk)
        for t in range(done, done + chunk):
            step = explorer.step()
            got = (fast.states[t], fast.actions[t], fast.modes[t], fast.labels[t])
            assert got == (step.state, step.action, step.mode, step.label), f"experiment {t}"
        done += chunk
        _compare_banks(bank, ref_bank)
    assert done == n
    fast.sync()
    assert (world.level, world.on_top, world.below) == (
        ref_world.level,
        ref_world.on_top,
        ref_world.below,
    )
    assert world._rng.getstate() == ref_world._rng.getstate()
    assert agent.rng.getstate() == ref_strategy.rng.getstate()
    assert fast.plan_calls == getattr(getattr(ref_strategy, "planner", None), "calls", 0)


@pytest.mark.parametrize("strategy", sorted(fastpath.FAST_STRATEGIES))
def test_fast_and_reference_runs_give_the_same_results(strategy: str) -> None:
    config = RunConfig(
        strategy=strategy, seed=5, experiments=2500, record_every=100, snapshots=(700,)
    )
    fast = run(config, engine="fast")
    reference = run(config, engine="reference")
    for name in ("states", "actions", "modes", "labels", "record_at", "snapshot_at"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(reference, name))
    np.testing.assert_allclose(fast.kl, reference.kl, rtol=0, atol=1e-9)
    np.testing.assert_allclose(fast.snapshot_margin, reference.snapshot_margin, atol=1e-9)
    np.testing.assert_array_equal(fast.snapshot_unknown, reference.snapshot_unknown)
    assert fast.plan_calls == reference.plan_calls


def test_progress_is_reported_for_every_experiment_on_the_fast_path() -> None:
    seen: list[int] = []
    run(RunConfig(strategy="q1", seed=0, experiments=1050), progress=seen.append,
        progress_every=100)
    assert sum(seen) == 1050 and seen[-1] == 50


def test_engine_choice_is_validated() -> None:
    with pytest.raises(ValueError, match="engine"):
        run(RunConfig(experiments=10), engine="turbo")
    with pytest.raises(ValueError, match="no fast path"):
        run(RunConfig(strategy="lp", experiments=10), engine="fast")


def test_fast_path_refuses_what_it_does_not_reproduce() -> None:
    config = RunConfig(strategy="q1", experiments=10)
    world, bank, strategy = build_run(config)
    world.shuffle_scan = False  # an explicit scan order is the reference's business
    assert not fastpath.supports(world, bank)
    with pytest.raises(ValueError, match="abstract world"):
        fastpath.FastRun("q1", world, bank, strategy.rng, GAMMA, 10)
    with pytest.raises(ValueError, match="no fast path"):
        fastpath.FastRun("lp", world, bank, strategy.rng, GAMMA, 10)
    world.shuffle_scan = True
    fast = fastpath.FastRun("q1", world, bank, strategy.rng, GAMMA, 10)
    with pytest.raises(ValueError, match="advance past"):
        fast.advance(11)


def test_the_experiments_module_knows_which_strategies_are_fast() -> None:
    assert set(FAST_STRATEGY_NAMES) == set(fastpath.FAST_STRATEGIES)
