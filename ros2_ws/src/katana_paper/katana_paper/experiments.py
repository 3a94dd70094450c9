"""The paper's simulated experiments: every method on every seed in the abstract world."""

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
from katana_curiosity.core.explorer import (
    PLAN,
    QUERY,
    STRATEGIES,
    Explorer,
    Strategy,
    make_strategy,
)
from katana_curiosity.core.predictors import PredictorBank, QueryRule

from .metrics import cumulative_by_state, model_kl

DEFAULT_METHODS = ("q1", "q10", "conf", "random")
FAST_METHOD_NAMES = ("q1", "q10", "conf", "random")  # fastpath.FAST_METHODS, without numba
DEFAULT_SNAPSHOTS = (1000, 2000, 3000, 4000)


@dataclass(frozen=True)
class RunConfig:
    """One run: a method on a seed. Defaults are the paper's simulation (section 3)."""

    method: str = "q1"
    seed: int = 0
    steps: int = 10_000
    n_blocks: int = 8
    n_features: int = 21
    alpha: float = 1.0
    theta: float = 0.01
    gamma: float = 0.95
    record_every: int = 50
    snapshots: tuple[int, ...] = DEFAULT_SNAPSHOTS

    def __post_init__(self) -> None:
        if self.method not in STRATEGIES:
            raise ValueError(
                f"unknown method {self.method!r}: choose from {', '.join(sorted(STRATEGIES))}"
            )
        if self.steps < 1:
            raise ValueError(f"steps must be >= 1, got {self.steps}")
        if self.record_every < 1:
            raise ValueError(f"record_every must be >= 1, got {self.record_every}")
        if not 0.0 <= self.gamma < 1.0:
            raise ValueError(f"gamma must be in [0, 1), got {self.gamma}")
        QueryRule(self.alpha, self.theta)  # validates alpha and theta


@dataclass
class RunResult:
    """Everything the figures need from one run (plain arrays: saved as CSV and npz)."""

    config: RunConfig
    states: np.ndarray  # (steps,) state of each experiment
    actions: np.ndarray  # (steps,) action index of each experiment
    modes: np.ndarray  # (steps,) QUERY, PLAN or RANDOM
    labels: np.ndarray  # (steps,) +1 / -1
    record_steps: np.ndarray  # (r,) steps at which the KL was recorded
    kl: np.ndarray  # (r, heights) KL(true || learned) per learned height
    heights: np.ndarray  # the learned heights (1..7)
    true_margin: np.ndarray  # (n_states, n_actions)
    snapshot_steps: np.ndarray  # (k,)
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
        at = self.record_steps if at is None else at
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
    strategy = make_strategy(config.method, bank, world.top, config.gamma, seed=int(agent_seed))
    return world, bank, strategy


def run(
    config: RunConfig,
    progress: Callable[[int], object] | None = None,
    progress_every: int = 100,
    engine: str = "auto",
) -> RunResult:
    """One run of `config.method` in the abstract world; deterministic for `config.seed`.

    progress(k) is called after every `progress_every` steps with k, the steps just done.
    engine: "reference" steps the NumPy Explorer; "fast" the compiled loop of core.fastpath
    (same trajectory; q1, q10, conf and random only); "auto" the fast one where it exists.
    """
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {', '.join(ENGINES)}, got {engine!r}")
    if progress_every < 1:
        raise ValueError(f"progress_every must be >= 1, got {progress_every}")
    world, bank, strategy = build_run(config)
    fast = None
    if engine != "reference":
        from katana_curiosity.core import fastpath  # numba: imported only when a run uses it

        if config.method in fastpath.FAST_METHODS and fastpath.supports(world, bank):
            fast = fastpath.FastRun(
                config.method, world, bank, strategy.rng, config.gamma, config.steps
            )
        elif engine == "fast":
            raise ValueError(f"no fast path for method {config.method!r}")
    explorer = Explorer(world, bank, strategy)
    heights = np.array(world.learned_heights)
    true_margin = np.vstack([world.true_margin, np.zeros((1, world.n_actions))])

    n = config.steps
    states = np.empty(n, dtype=np.int16)
    actions = np.empty(n, dtype=np.int16)
    modes = np.empty(n, dtype=np.int8)
    labels = np.empty(n, dtype=np.int8)
    record_steps = np.unique(
        np.r_[0, np.arange(config.record_every, n + 1, config.record_every), n]
    )
    # Learned margins at every recorded step; the KL of all of them is computed at the end.
    recorded = np.empty((len(record_steps), len(heights), world.n_actions))
    snap_steps = np.array(sorted({s for s in config.snapshots if 0 < s <= n} | {n}))
    snap_margin = np.empty((len(snap_steps), *bank.margin.shape))
    snap_chi = np.empty_like(snap_margin)
    snap_unknown = np.empty(snap_margin.shape, dtype=bool)

    record_at = {int(s): i for i, s in enumerate(record_steps)}
    snap_at = {int(s): i for i, s in enumerate(snap_steps)}
    recorded[0] = bank.margin[heights]

    def observe(done: int) -> None:
        if done in record_at:
            recorded[record_at[done]] = bank.margin[heights]
        if done in snap_at:
            i = snap_at[done]
            snap_margin[i], snap_chi[i], snap_unknown[i] = bank.margin, bank.chi, bank.unknown
        if progress is not None and (done % progress_every == 0 or done == n):
            progress(done % progress_every or progress_every)

    start = time.perf_counter()
    if fast is not None:
        # Compiled chunks between the steps where something is recorded or reported.
        stops = set(record_at) | set(snap_at) | {n}
        if progress is not None:
            stops |= set(range(progress_every, n + 1, progress_every))
        for done in sorted(s for s in stops if s > 0):
            fast.advance(done - fast.done)
            observe(done)
        fast.sync()
        states, actions, modes, labels = fast.states, fast.actions, fast.modes, fast.labels
        plan_calls = fast.plan_calls
    else:
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
        plan_calls = getattr(getattr(strategy, "planner", None), "calls", 0)
    kl = model_kl(true_margin[heights], recorded)  # (records, heights)
    wall = time.perf_counter() - start
    return RunResult(
        config,
        states,
        actions,
        modes,
        labels,
        record_steps,
        kl,
        heights,
        true_margin,
        snap_steps,
        snap_margin,
        snap_chi,
        snap_unknown,
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
        if any(c.method in FAST_METHOD_NAMES for c in configs):
            from katana_curiosity.core.fastpath import warm_up

            warm_up()  # load (or compile) once here: forked workers inherit the machine code
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            futures = {pool.submit(_run_quiet, c): i for i, c in enumerate(configs)}
            for future in as_completed(futures):
                results[futures[future]] = future.result()
                if progress:
                    progress(results[futures[future]])
    return [r for r in results if r is not None]


# -- outputs ---------------------------------------------------------------------------------


def write_run_csv(result: RunResult, path: Path) -> None:
    """One row per recorded step: KL per height and cumulative direct/planned experience."""
    direct = result.cumulative(QUERY)
    planned = result.cumulative(PLAN)
    heights = result.heights.tolist()
    states = range(result.n_states - 1)
    header = (
        ["step"]
        + [f"kl_{h}" for h in heights]
        + ["kl_overall"]
        + [f"direct_{s}" for s in states]
        + [f"planned_{s}" for s in states]
    )
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        for i, step in enumerate(result.record_steps):
            writer.writerow(
                [int(step)]
                + [f"{v:.6g}" for v in result.kl[i]]
                + [f"{result.kl[i].mean():.6g}"]
                + [int(direct[i, s]) for s in states]
                + [int(planned[i, s]) for s in states]
            )


def summarise(results: Sequence[RunResult]) -> dict:
    """summary.json: final KL per method and height (mean over seeds), and how they explored."""
    if not results:
        raise ValueError("no results to summarise")
    methods: dict[str, dict] = {}
    for method in dict.fromkeys(r.config.method for r in results):
        runs = [r for r in results if r.config.method == method]
        final = np.array([r.kl[-1] for r in runs])  # (seeds, heights)
        heights = runs[0].heights.tolist()
        steps = sum(r.config.steps for r in runs)
        methods[method] = {
            "final_kl": {str(h): float(final[:, i].mean()) for i, h in enumerate(heights)},
            "final_kl_std": {str(h): float(final[:, i].std()) for i, h in enumerate(heights)},
            "final_kl_overall": float(final.mean()),
            "direct_experience": _mean_counts(runs, QUERY),
            "planned_experience": _mean_counts(runs, PLAN),
            "highest_state_tried": float(np.mean([r.states.max() for r in runs])),
            "plan_calls": float(np.mean([r.plan_calls for r in runs])),
            "steps_per_s": steps / max(sum(r.wall_s for r in runs), 1e-9),
        }
    first = results[0].config
    return {
        "steps": first.steps,
        "seeds": sorted({r.config.seed for r in results}),
        "parameters": {
            "n_blocks": first.n_blocks,
            "n_features": first.n_features,
            "alpha": first.alpha,
            "theta": first.theta,
            "gamma": first.gamma,
        },
        "methods": methods,
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
        write_run_csv(r, runs_dir / f"{r.config.method}_seed{r.config.seed}.csv")
    summary = summarise(results)
    with open(out / "summary.json", "w") as f:
        json.dump(summary, f, indent=2)
        f.write("\n")
    return summary
