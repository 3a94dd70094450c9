"""Curiosity core speed: steps per second per method, one planning call, the default paper run."""

from __future__ import annotations

import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np
from katana_curiosity.core.abstract_world import AbstractBlocksWorld
from katana_curiosity.core.explorer import Explorer, make_strategy
from katana_curiosity.core.planner import Planner
from katana_curiosity.core.predictors import PredictorBank, QueryRule

TARGETS = {"q1_steps_per_s": 50_000, "q1_steps_per_s_minimum": 20_000, "paper_default_wall_s": 30}


def steps_per_s(method: str, steps: int = 10_000, repeats: int = 3) -> float:
    rates = []
    for seed in range(repeats):
        world = AbstractBlocksWorld(seed=seed)
        bank = PredictorBank(
            world.learned_heights, world.features, QueryRule(1.0, 0.01), n_states=world.top + 1
        )
        explorer = Explorer(world, bank, make_strategy(method, bank, world.top, seed=seed))
        step = explorer.step
        start = time.perf_counter()
        for _ in range(steps):
            step()
        rates.append(steps / (time.perf_counter() - start))
    return statistics.median(rates)


def plan_ms(calls: int = 2000) -> dict[str, float]:
    """One planning call at 7 heights x 21 actions, after a model update (as in a run) and cold."""
    rng = np.random.default_rng(0)
    world = AbstractBlocksWorld(seed=0)
    bank = PredictorBank(
        world.learned_heights, world.features, QueryRule(1.0, 0.01), n_states=world.top + 1
    )
    for _ in range(3000):
        bank.update(int(rng.integers(1, 8)), int(rng.integers(21)), float(rng.choice([-1, 1])))
    planner = Planner(bank, world.top)
    planner.solve()
    warm, cold = [], []
    for _ in range(calls):
        bank.update(int(rng.integers(1, 8)), int(rng.integers(21)), float(rng.choice([-1, 1])))
        start = time.perf_counter()
        planner.solve()
        warm.append(time.perf_counter() - start)
    for _ in range(calls // 10):
        fresh = Planner(bank, world.top)
        start = time.perf_counter()
        fresh.solve()
        cold.append(time.perf_counter() - start)
    return {"plan_ms": statistics.median(warm) * 1e3, "plan_cold_ms": statistics.median(cold) * 1e3}


def paper_default_wall_s() -> float:
    with tempfile.TemporaryDirectory() as out:
        start = time.perf_counter()
        subprocess.run(
            [sys.executable, "-m", "katana_curiosity", "paper", "--jobs", "2", "--out", out],
            check=True,
            capture_output=True,
        )
        return time.perf_counter() - start


def run() -> dict:
    rates = {m: round(steps_per_s(m)) for m in ("q1", "q10", "conf", "random")}
    return {
        "steps_per_s": rates,
        **{k: round(v, 4) for k, v in plan_ms().items()},
        "paper_default_wall_s": round(paper_default_wall_s(), 2),
        "targets": TARGETS,
        "notes": "steps_per_s: median of 3 runs of 10,000 steps, one process; plan_ms: median "
        "of one Planner.solve after a model update (warm start, incremental MDP), "
        "plan_cold_ms from a fresh planner; paper_default_wall_s: `katana-curiosity "
        "paper --jobs 2` with defaults (4 methods x 10 seeds x 10,000 steps, figures).",
    }
