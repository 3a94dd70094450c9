"""Parameter sweeps of the abstract world on Ray: every cell x seed x strategy as one Ray task.

A local Ray on this machine by default (num_cpus workers), an existing cluster with `address`
(its nodes need this package installed, as on this machine). Rows are appended to sweep.csv as
runs finish, so an interrupted sweep resumes: rows already in the file (same strategy, seed,
experiments and parameters) are not run again; a sweep.csv of before the renaming (columns
"method" and "steps") is read as well. summary.json and sensitivity.png are written from the
rows of the sweep asked for.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from katana_curiosity.core.explorer import PLAN, QUERY, RANDOM
from katana_curiosity.core.strategies import STRATEGIES
from tqdm import tqdm

from .experiments import FAST_STRATEGY_NAMES, RunConfig, run
from .ray_session import ray_session

# What a grid may sweep, with its type; every other RunConfig field is fixed for the sweep.
SWEEPABLE: dict[str, type] = {
    "alpha": float,
    "theta": float,
    "gamma": float,
    "n_blocks": int,
    "n_features": int,
}
PARAMETERS = tuple(SWEEPABLE)  # the columns identifying a run, with strategy, seed, experiments
DEFAULT_GRID = {"alpha": (0.5, 1.0, 2.0), "theta": (0.001, 0.01, 0.1)}
DEFAULT_SWEEP_STRATEGIES = ("q1", "random")
#: columns of a sweep.csv written before "one word per concept": old name -> name
RENAMED_COLUMNS = {"method": "strategy", "steps": "experiments"}


def parse_grid_axis(text: str) -> tuple[str, tuple[float | int, ...]]:
    """'alpha=0.5,1,2' -> ('alpha', (0.5, 1.0, 2.0)); ValueError naming what is wrong."""
    name, sep, values = text.partition("=")
    name = name.strip()
    if not sep or name not in SWEEPABLE:
        raise ValueError(
            f"grid axis must be NAME=V1,V2,... with NAME one of {', '.join(SWEEPABLE)}; "
            f"got {text!r}"
        )
    kind = SWEEPABLE[name]
    try:
        parsed = tuple(kind(v) for v in values.split(",") if v.strip())
    except ValueError:
        raise ValueError(
            f"grid axis {name}: values must be {kind.__name__}s, got {values!r}"
        ) from None
    if not parsed or len(set(parsed)) != len(parsed):
        raise ValueError(f"grid axis {name}: needs distinct values, got {values!r}")
    return name, parsed


@dataclass(frozen=True)
class SweepSpec:
    """The grid (axis -> values), the strategies, the seeds and the run length of a sweep."""

    grid: dict[str, tuple] = field(default_factory=lambda: dict(DEFAULT_GRID))
    strategies: tuple[str, ...] = DEFAULT_SWEEP_STRATEGIES
    seeds: int = 20
    first_seed: int = 0
    experiments: int = 10_000
    base: dict[str, float | int] = field(default_factory=dict)  # fixed values of other fields

    def __post_init__(self) -> None:
        unknown = [m for m in self.strategies if m not in STRATEGIES]
        if not self.strategies or unknown:
            raise ValueError(f"unknown strategy(s) {unknown}: choose from {sorted(STRATEGIES)}")
        bad = [k for k in (*self.grid, *self.base) if k not in SWEEPABLE]
        if bad:
            raise ValueError(f"cannot sweep or fix {bad}: choose from {', '.join(SWEEPABLE)}")
        if self.seeds < 1 or self.experiments < 1:
            raise ValueError("seeds and experiments must be >= 1")
        self.configs()  # RunConfig validates every cell's values (alpha > 0, ...)

    def cells(self) -> list[dict[str, float | int]]:
        names = list(self.grid)
        return [
            dict(zip(names, values, strict=True))
            for values in itertools.product(*self.grid.values())
        ]

    def configs(self) -> list[RunConfig]:
        return [
            RunConfig(strategy=m, seed=s, experiments=self.experiments, **{**self.base, **cell})
            for cell in self.cells()
            for s in range(self.first_seed, self.first_seed + self.seeds)
            for m in self.strategies
        ]


def run_key(row: dict) -> tuple:
    """What identifies a run in sweep.csv: strategy, seed, experiments and every parameter."""
    return (
        str(row["strategy"]),
        int(row["seed"]),
        int(row["experiments"]),
        *(SWEEPABLE[p](row[p]) for p in PARAMETERS),
    )


def config_row(config: RunConfig) -> dict:
    fields = asdict(config)
    return {
        "strategy": config.strategy,
        "seed": config.seed,
        "experiments": config.experiments,
        **{p: fields[p] for p in PARAMETERS},
    }


def run_row(config_fields: dict) -> dict:
    """One run, reduced to its sweep.csv row (what a Ray task returns: plain values)."""
    config = RunConfig(**config_fields)
    result = run(config)
    final = result.kl[-1]
    row = config_row(config)
    row.update(
        {
            "final_kl_overall": float(final.mean()),
            **{f"final_kl_{h}": float(v) for h, v in zip(result.heights, final, strict=True)},
            "highest_state": int(result.states.max()),
            "queries": int(np.sum(result.modes == QUERY)),
            "plans": int(np.sum(result.modes == PLAN)),
            "randoms": int(np.sum(result.modes == RANDOM)),
            "plan_calls": int(result.plan_calls),
            "wall_s": round(result.wall_s, 4),
        }
    )
    return row


def read_rows(path: Path) -> list[dict]:
    """The complete rows of sweep.csv (a row cut short by a crash is left out: it runs again),
    with the columns of an older file under their names of now (in the file's order)."""
    if not path.exists():
        return []
    _drop_cut_line(path)
    with open(path, newline="") as f:
        rows = [{RENAMED_COLUMNS.get(k, k): v for k, v in r.items()} for r in csv.DictReader(f)]
    return [r for r in rows if _complete(r)]


def _complete(row: dict) -> bool:
    try:
        run_key(row)
        float(row["final_kl_overall"])
    except (KeyError, TypeError, ValueError):
        return False
    return True


def _drop_cut_line(path: Path) -> None:
    """Truncate a last line without its newline, so that appended rows start on a new line."""
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        with open(path, "r+b") as f:
            f.truncate(data.rfind(b"\n") + 1)


def run_sweep(
    spec: SweepSpec,
    out: Path,
    address: str | None = None,
    num_cpus: int = 2,
    progress: bool = True,
    figures: bool = True,
    on_row: Callable[[dict], None] | None = None,
) -> dict:
    """Run what sweep.csv in `out` does not hold yet, then write summary.json and the figure.

    Uses the Ray session of this process if there is one; otherwise starts a local Ray with
    `num_cpus` CPUs (address None) or connects to the cluster at `address`, and shuts it down
    afterwards. Returns the summary, with "ran" (runs executed now) and "reused" (found).
    """
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / "sweep.csv"
    existing = read_rows(csv_path)
    done = {run_key(r) for r in existing}
    configs = spec.configs()
    todo = [c for c in configs if run_key(config_row(c)) not in done]
    ran = 0
    if todo:
        if any(c.strategy in FAST_STRATEGY_NAMES for c in todo):
            from katana_curiosity.core.fastpath import warm_up  # noqa: PLC0415 - numba: only for fast runs

            warm_up()  # compiles once here rather than in every worker on a fresh checkout
        with ray_session(address, num_cpus) as ray:
            header = list(existing[0]) if existing else csv_header(spec)
            ran = _submit(ray, todo, csv_path, header, progress, on_row)
    wanted = {run_key(config_row(c)) for c in configs}
    rows = [r for r in read_rows(csv_path) if run_key(r) in wanted]
    summary = summarise_sweep(spec, rows)
    summary["ran"], summary["reused"] = ran, len(configs) - ran
    with open(out / "summary.json", "w") as f:
        json.dump(summary, f, indent=2)
        f.write("\n")
    if figures:
        from .figures import sensitivity_figure  # noqa: PLC0415 - matplotlib only when figures are wanted

        sensitivity_figure(spec, rows, out / "sensitivity.png")
    return summary


def csv_header(spec: SweepSpec) -> list[str]:
    """sweep.csv's columns: a KL column for every height any cell of the sweep has."""
    most = max(c.n_blocks for c in spec.configs())
    return [
        "strategy",
        "seed",
        "experiments",
        *PARAMETERS,
        "final_kl_overall",
        *(f"final_kl_{h}" for h in range(1, most)),
        "highest_state",
        "queries",
        "plans",
        "randoms",
        "plan_calls",
        "wall_s",
    ]


def _submit(ray, todo, csv_path, header, progress, on_row) -> int:
    task = ray.remote(num_cpus=1)(run_row)
    pending = [task.remote(asdict(c)) for c in todo]
    ran = 0
    with (
        open(csv_path, "a", newline="") as f,
        tqdm(
            total=len(todo), desc="sweep", unit="run", file=sys.stderr, disable=not progress
        ) as bar,
    ):
        writer = csv.DictWriter(f, fieldnames=header, restval="", extrasaction="ignore")
        if f.tell() == 0:
            writer.writeheader()
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            row = ray.get(ready[0])
            writer.writerow(row)
            f.flush()  # a finished run survives an interruption
            ran += 1
            bar.update(1)
            if on_row is not None:
                on_row(row)
    return ran


# -- outputs ---------------------------------------------------------------------------------


def _stats(values: Sequence[float]) -> dict[str, float]:
    v = np.asarray(values, dtype=float)
    return {
        "mean": float(v.mean()),
        "std": float(v.std()),
        "min": float(v.min()),
        "max": float(v.max()),
        "n": int(v.size),
    }


def summarise_sweep(spec: SweepSpec, rows: Sequence[dict]) -> dict:
    """Final overall KL per cell and strategy, and per value of each swept parameter."""
    cells = []
    for cell in spec.cells():
        entry = {"parameters": cell, "strategies": {}}
        for m in spec.strategies:
            kl = [float(r["final_kl_overall"]) for r in rows if matches(r, cell, m)]
            if kl:
                entry["strategies"][m] = {"final_kl_overall": _stats(kl)}
        cells.append(entry)
    marginal = {}
    for name, values in spec.grid.items():
        marginal[name] = {
            m: {
                str(v): _stats(
                    [
                        float(r["final_kl_overall"])
                        for r in rows
                        if r["strategy"] == m and math.isclose(float(r[name]), float(v))
                    ]
                    or [math.nan]
                )
                for v in values
            }
            for m in spec.strategies
        }
    return {
        "grid": {k: list(v) for k, v in spec.grid.items()},
        "strategies": list(spec.strategies),
        "seeds": list(range(spec.first_seed, spec.first_seed + spec.seeds)),
        "experiments": spec.experiments,
        "base": dict(spec.base),
        "runs": len(rows),
        "cells": cells,
        "by_parameter": marginal,
    }


def matches(row: dict, cell: dict, strategy: str) -> bool:
    """The row is a run of `strategy` in `cell`."""
    return row["strategy"] == strategy and all(
        math.isclose(float(row[k]), float(v)) for k, v in cell.items()
    )
