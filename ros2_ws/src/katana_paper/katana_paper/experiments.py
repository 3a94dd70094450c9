"""The paper's simulated experiments: every strategy on every seed in the abstract world."""

from __future__ import annotations

import csv
import json
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from katana_curiosity.core.abstract_world import AbstractBlocksWorld
from katana_curiosity.core.explorer import PLAN, QUERY, Explorer, Strategy
from katana_curiosity.core.predictors import (
    ALPHA,
    GAMMA,
    THETA_ABSTRACT,
    PredictorBank,
    QueryRule,
)
from katana_curiosity.core.strategies import STRATEGIES, make_strategy

from .metrics import cumulative_by_state, model_kl
from .processes import worker_context

DEFAULT_STRATEGIES = ("q1", "q10", "conf", "random")
FAST_STRATEGY_NAMES = ("q1", "q10", "conf", "random")  # fastpath.FAST_STRATEGIES, without numba
DEFAULT_SNAPSHOTS = (1000, 2000, 3000, 4000)


@dataclass(frozen=True)
class RunConfig:
    """One run: a strategy on a seed. Defaults are the paper's simulation (section 3)."""

    strategy: str = "q1"
    seed: int = 0
    experiments: int = 10_000
    n_blocks: int = 8
    n_features: int = 21
    alpha: float = ALPHA
    theta: float = THETA_ABSTRACT
    gamma: float = GAMMA
    record_every: int = 50  # experiments between two KL records
    snapshots: tuple[int, ...] = DEFAULT_SNAPSHOTS  # after these experiments, the whole model

    def __post_init__(self) -> None:
        if self.strategy not in STRATEGIES:
            raise ValueError(
                f"unknown strategy {self.strategy!r}: choose from {', '.join(sorted(STRATEGIES))}"
            )
        if self.experiments < 1:
            raise ValueError(f"experiments must be >= 1, got {self.experiments}")
        if self.record_every < 1:
            raise ValueError(f"record_every must be >= 1, got {self.record_every}")
        if not 0.0 <= self.gamma < 1.0:
            raise ValueError(f"gamma must be in [0, 1), got {self.gamma}")
        QueryRule(self.alpha, self.theta)  # validates alpha and theta


@dataclass
class RunResult:
    """Everything the figures need from one run (plain arrays: saved as CSV and npz)."""

    config: RunConfig
    states: np.ndarray  # (experiments,) state of each experiment
    actions: np.ndarray  # (experiments,) action index of each experiment
    modes: np.ndarray  # (experiments,) QUERY, PLAN or RANDOM
    labels: np.ndarray  # (experiments,) +1 / -1
    record_at: np.ndarray  # (r,) experiments done when the KL was recorded
    kl: np.ndarray  # (r, heights) KL(true || learned) per learned height
    heights: np.ndarray  # the learned heights (1..7)
    true_margin: np.ndarray  # (n_states, n_actions)
    snapshot_at: np.ndarray  # (k,) experiments done at each snapshot
    snapshot_margin: np.ndarray  # (k, n_states, n_actions)
    snapshot_chi: np.ndarray
    snapshot_unknown: np.ndarray
    wall_s: float = 0.0
    plan_calls: int = 0
    extra: dict = field(default_factory=dict)

    @property
    def n_states(self) -> int:
        return self.true_margin.shape[0]

    def cumulative(self, mode: int, at: np.ndarray | None = None) -> np.ndarray:
        at = self.record_at if at is None else at
        return cumulative_by_state(self.states, self.modes == mode, self.n_states, at)


ENGINES = ("auto", "fast", "reference")


def build_run(config: RunConfig) -> tuple[AbstractBlocksWorld, PredictorBank, Strategy]:
    """The world, bank and strategy of a run, seeded from config.seed."""
    world_seed, agent_seed = np.random.SeedSequence(config.seed).generate_state(2)
    world = AbstractBlocksWorld(config.n_blocks, config.n_features, seed=int(world_seed))
    bank = PredictorBank(
        world.learned_heights,
        world.features,
        QueryRule(config.alpha, config.theta),
        n_states=world.top + 1,
    )
    strategy = make_strategy(config.strategy, bank, world.top, config.gamma, seed=int(agent_seed))
    return world, bank, strategy


class _Records:
    """What a run keeps of its model while it runs: the learned margins of the learned heights
    at every recorded experiment count (their KL is computed at the end) and whole-model
    snapshots."""

    def __init__(self, config: RunConfig, bank: PredictorBank, heights: np.ndarray) -> None:
        n = config.experiments
        self.bank, self.heights = bank, heights
        self.record_at = np.unique(
            np.r_[0, np.arange(config.record_every, n + 1, config.record_every), n]
        )
        self.margins = np.empty((len(self.record_at), len(heights), bank.margin.shape[1]))
        self.snapshot_at = np.array(sorted({s for s in config.snapshots if 0 < s <= n} | {n}))
        self.snap_margin = np.empty((len(self.snapshot_at), *bank.margin.shape))
        self.snap_chi = np.empty_like(self.snap_margin)
        self.snap_unknown = np.empty(self.snap_margin.shape, dtype=bool)
        self._record_index = {int(s): i for i, s in enumerate(self.record_at)}
        self._snap_index = {int(s): i for i, s in enumerate(self.snapshot_at)}
        self.margins[0] = bank.margin[heights]

    def stops(self) -> set[int]:
        """The experiment counts at which something is kept."""
        return set(self._record_index) | set(self._snap_index)

    def observe(self, done: int) -> None:
        bank = self.bank
        if done in self._record_index:
            self.margins[self._record_index[done]] = bank.margin[self.heights]
        if done in self._snap_index:
            i = self._snap_index[done]
            self.snap_margin[i], self.snap_chi[i] = bank.margin, bank.chi
            self.snap_unknown[i] = bank.unknown


def _fast_run(config: RunConfig, world, bank, strategy, engine: str):
    """The compiled loop of core.fastpath for this run, or None (the reference Explorer runs it)."""
    if engine == "reference":
        return None
    from katana_curiosity.core import fastpath  # noqa: PLC0415 - numba: imported only when a run uses it

    if config.strategy in fastpath.FAST_STRATEGIES and fastpath.supports(world, bank):
        return fastpath.FastRun(
            config.strategy, world, bank, strategy.rng, config.gamma, config.experiments
        )
    if engine == "fast":
        raise ValueError(f"no fast path for strategy {config.strategy!r}")
    return None


def _run_fast(fast, stops: set[int], observe: Callable[[int], None]):
    """Compiled chunks between the experiment counts where something is kept or reported."""
    for done in sorted(s for s in stops if s > 0):
        fast.advance(done - fast.done)
        observe(done)
    fast.sync()
    return (fast.states, fast.actions, fast.modes, fast.labels), fast.plan_calls


def _run_reference(explorer: Explorer, n: int, observe: Callable[[int], None]):
    """n experiments of the NumPy Explorer, observing after each."""
    states = np.empty(n, dtype=np.int16)
    actions = np.empty(n, dtype=np.int16)
    modes = np.empty(n, dtype=np.int8)
    labels = np.empty(n, dtype=np.int8)
    step = explorer.step
    for t in range(n):
        result = step()
        states[t], actions[t], modes[t], labels[t] = (
            result.state,
            result.action,
            result.mode,
            result.label,
        )
        observe(t + 1)
    plan_calls = getattr(getattr(explorer.strategy, "planner", None), "calls", 0)
    return (states, actions, modes, labels), plan_calls


def run(
    config: RunConfig,
    progress: Callable[[int], object] | None = None,
    progress_every: int = 100,
    engine: str = "auto",
) -> RunResult:
    """One run of `config.strategy` in the abstract world; deterministic for `config.seed`.

    progress(k) is called after every `progress_every` experiments with k, the experiments
    just done. engine: "reference" runs the NumPy Explorer; "fast" the compiled loop of
    core.fastpath (same trajectory; q1, q10, conf and random only); "auto" the fast one where
    it exists.
    """
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {', '.join(ENGINES)}, got {engine!r}")
    if progress_every < 1:
        raise ValueError(f"progress_every must be >= 1, got {progress_every}")
    world, bank, strategy = build_run(config)
    fast = _fast_run(config, world, bank, strategy, engine)
    heights = np.array(world.learned_heights)
    true_margin = np.vstack([world.true_margin, np.zeros((1, world.n_actions))])
    n = config.experiments
    records = _Records(config, bank, heights)

    def observe(done: int) -> None:
        records.observe(done)
        if progress is not None and (done % progress_every == 0 or done == n):
            progress(done % progress_every or progress_every)

    start = time.perf_counter()
    if fast is not None:
        stops = records.stops() | {n}
        if progress is not None:
            stops |= set(range(progress_every, n + 1, progress_every))
        trajectory, plan_calls = _run_fast(fast, stops, observe)
    else:
        trajectory, plan_calls = _run_reference(Explorer(world, bank, strategy), n, observe)
    kl = model_kl(true_margin[heights], records.margins)  # (records, heights)
    wall = time.perf_counter() - start
    return RunResult(
        config,
        *trajectory,
        records.record_at,
        kl,
        heights,
        true_margin,
        records.snapshot_at,
        records.snap_margin,
        records.snap_chi,
        records.snap_unknown,
        wall,
        plan_calls,
    )


def _run_quiet(config: RunConfig) -> RunResult:
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    return run(config)


def run_many(
    configs: Sequence[RunConfig],
    jobs: int = 1,
    progress: Callable[[RunResult], None] | None = None,
) -> list[RunResult]:
    """Run every config, in `jobs` worker processes; results in the order of `configs`."""
    if jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs}")
    results: list[RunResult | None] = [None] * len(configs)
    if jobs == 1:
        for i, config in enumerate(configs):
            results[i] = run(config)
            if progress:
                progress(results[i])
    else:
        if any(c.strategy in FAST_STRATEGY_NAMES for c in configs):
            from katana_curiosity.core.fastpath import warm_up  # noqa: PLC0415 - numba: only for fast runs

            warm_up()  # compile once here: the workers load the machine code from numba's cache
        with ProcessPoolExecutor(max_workers=jobs, mp_context=worker_context()) as pool:
            futures = {pool.submit(_run_quiet, c): i for i, c in enumerate(configs)}
            for future in as_completed(futures):
                results[futures[future]] = future.result()
                if progress:
                    progress(results[futures[future]])
    return [r for r in results if r is not None]


# -- outputs ---------------------------------------------------------------------------------


def write_run_csv(result: RunResult, path: Path) -> None:
    """One row per KL record: KL per height and cumulative direct/planned experience."""
    direct = result.cumulative(QUERY)
    planned = result.cumulative(PLAN)
    heights = result.heights.tolist()
    states = range(result.n_states - 1)
    header = (
        ["experiment"]
        + [f"kl_{h}" for h in heights]
        + ["kl_overall"]
        + [f"direct_{s}" for s in states]
        + [f"planned_{s}" for s in states]
    )
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        for i, done in enumerate(result.record_at):
            writer.writerow(
                [int(done)]
                + [f"{v:.6g}" for v in result.kl[i]]
                + [f"{result.kl[i].mean():.6g}"]
                + [int(direct[i, s]) for s in states]
                + [int(planned[i, s]) for s in states]
            )


def summarise(results: Sequence[RunResult]) -> dict:
    """summary.json: final KL per strategy and height (mean over seeds), and how they explored."""
    if not results:
        raise ValueError("no results to summarise")
    strategies: dict[str, dict] = {}
    for strategy in dict.fromkeys(r.config.strategy for r in results):
        runs = [r for r in results if r.config.strategy == strategy]
        final = np.array([r.kl[-1] for r in runs])  # (seeds, heights)
        heights = runs[0].heights.tolist()
        experiments = sum(r.config.experiments for r in runs)
        strategies[strategy] = {
            "final_kl": {str(h): float(final[:, i].mean()) for i, h in enumerate(heights)},
            "final_kl_std": {str(h): float(final[:, i].std()) for i, h in enumerate(heights)},
            "final_kl_overall": float(final.mean()),
            "direct_experience": _mean_counts(runs, QUERY),
            "planned_experience": _mean_counts(runs, PLAN),
            "highest_state_tried": float(np.mean([r.states.max() for r in runs])),
            "plan_calls": float(np.mean([r.plan_calls for r in runs])),
            "experiments_per_s": experiments / max(sum(r.wall_s for r in runs), 1e-9),
        }
    first = results[0].config
    return {
        "experiments": first.experiments,
        "seeds": sorted({r.config.seed for r in results}),
        "parameters": {
            "n_blocks": first.n_blocks,
            "n_features": first.n_features,
            "alpha": first.alpha,
            "theta": first.theta,
            "gamma": first.gamma,
        },
        "strategies": strategies,
    }


def _mean_counts(runs: Sequence[RunResult], mode: int) -> dict[str, float]:
    counts = np.array([np.bincount(r.states[r.modes == mode], minlength=r.n_states) for r in runs])
    return {str(s): float(c) for s, c in enumerate(counts.mean(axis=0)[:-1])}


def save_results(results: Sequence[RunResult], out: Path) -> dict:
    """Write summary.json and one CSV per run under `out`; returns the summary."""
    out.mkdir(parents=True, exist_ok=True)
    runs_dir = out / "runs"
    runs_dir.mkdir(exist_ok=True)
    for r in results:
        write_run_csv(r, runs_dir / f"{r.config.strategy}_seed{r.config.seed}.csv")
    summary = summarise(results)
    with open(out / "summary.json", "w") as f:
        json.dump(summary, f, indent=2)
        f.write("\n")
    return summary
