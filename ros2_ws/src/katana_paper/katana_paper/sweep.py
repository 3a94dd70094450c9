"""Parameter sweeps of the abstract world on Ray: every cell x seed x method as one Ray task.

A local Ray on this machine by default (num_cpus workers), an existing cluster with `address`
(its nodes need this package installed, as on this machine). Rows are appended to sweep.csv as
runs finish, so an interrupted sweep resumes: rows already in the file (same method, seed,
steps and parameters) are not run again. summary.json and sensitivity.png are written from the
rows of the sweep asked for.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from katana_curiosity.core.explorer import PLAN, QUERY, RANDOM, STRATEGIES

from .experiments import FAST_METHOD_NAMES, RunConfig, run

# What a grid may sweep, with its type; every other RunConfig field is fixed for the sweep.
SWEEPABLE: dict[str, type] = {
    "alpha": float,
    "theta": float,
    "gamma": float,
    "n_blocks": int,
    "n_features": int,
}
PARAMETERS = tuple(SWEEPABLE)  # the columns identifying a run, with method, seed and steps
DEFAULT_GRID = {"alpha": (0.5, 1.0, 2.0), "theta": (0.001, 0.01, 0.1)}
DEFAULT_SWEEP_METHODS = ("q1", "random")


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
    """The grid (axis -> values), the methods, the seeds and the run length of a sweep."""

    grid: dict[str, tuple] = field(default_factory=lambda: dict(DEFAULT_GRID))
    methods: tuple[str, ...] = DEFAULT_SWEEP_METHODS
    seeds: int = 20
    first_seed: int = 0
    steps: int = 10_000
    base: dict[str, float | int] = field(default_factory=dict)  # fixed values of other fields

    def __post_init__(self) -> None:
        unknown = [m for m in self.methods if m not in STRATEGIES]
        if not self.methods or unknown:
            raise ValueError(f"unknown method(s) {unknown}: choose from {sorted(STRATEGIES)}")
        bad = [k for k in (*self.grid, *self.base) if k not in SWEEPABLE]
        if bad:
            raise ValueError(f"cannot sweep or fix {bad}: choose from {', '.join(SWEEPABLE)}")
        if self.seeds < 1 or self.steps < 1:
            raise ValueError("seeds and steps must be >= 1")
        self.configs()  # RunConfig validates every cell's values (alpha > 0, ...)

    def cells(self) -> list[dict[str, float | int]]:
        names = list(self.grid)
        return [
            dict(zip(names, values, strict=True))
            for values in itertools.product(*self.grid.values())
        ]

    def configs(self) -> list[RunConfig]:
        return [
            RunConfig(method=m, seed=s, steps=self.steps, **{**self.base, **cell})
            for cell in self.cells()
            for s in range(self.first_seed, self.first_seed + self.seeds)
            for m in self.methods
        ]


def run_key(row: dict) -> tuple:
    """What identifies a run in sweep.csv: method, seed, steps and every parameter."""
    return (
        str(row["method"]),
        int(row["seed"]),
        int(row["steps"]),
        *(SWEEPABLE[p](row[p]) for p in PARAMETERS),
    )


def config_row(config: RunConfig) -> dict:
    fields = asdict(config)
    return {
        "method": config.method,
        "seed": config.seed,
        "steps": config.steps,
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
    """The complete rows of sweep.csv (a row cut short by a crash is left out: it runs again)."""
    if not path.exists():
        return []
    _drop_cut_line(path)
    with open(path, newline="") as f:
        return [r for r in csv.DictReader(f) if _complete(r)]


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


def _ray():
    # No network at run time: Ray's usage statistics stay off (set before ray is imported).
    os.environ["RAY_USAGE_STATS_ENABLED"] = "0"
    import ray

    return ray


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
        if any(c.method in FAST_METHOD_NAMES for c in todo):
            from katana_curiosity.core.fastpath import warm_up

            warm_up()  # compiles once here rather than in every worker on a fresh checkout
        ray = _ray()
        started = not ray.is_initialized()
        if started:
            local = {} if address else {"_node_ip_address": "127.0.0.1"}
            ray.init(
                address=address or "local",
                num_cpus=None if address else num_cpus,
                # a local Ray binds to loopback and never looks up a route to the internet
                **local,
                include_dashboard=False,
                log_to_driver=False,
                configure_logging=True,
                logging_level="WARNING",
            )
        try:
            header = list(existing[0]) if existing else csv_header(spec)
            ran = _submit(ray, todo, csv_path, header, progress, on_row)
        finally:
            if started:
                ray.shutdown()
    wanted = {run_key(config_row(c)) for c in configs}
    rows = [r for r in read_rows(csv_path) if run_key(r) in wanted]
    summary = summarise_sweep(spec, rows)
    summary["ran"], summary["reused"] = ran, len(configs) - ran
    with open(out / "summary.json", "w") as f:
        json.dump(summary, f, indent=2)
        f.write("\n")
    if figures:
        sensitivity_figure(spec, rows, out / "sensitivity.png")
    return summary


def csv_header(spec: SweepSpec) -> list[str]:
    """sweep.csv's columns: a KL column for every height any cell of the sweep has."""
    most = max(c.n_blocks for c in spec.configs())
    return [
        "method",
        "seed",
        "steps",
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
    from tqdm import tqdm

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
    """Final overall KL per cell and method, and per value of each swept parameter."""
    cells = []
    for cell in spec.cells():
        entry = {"parameters": cell, "methods": {}}
        for m in spec.methods:
            kl = [float(r["final_kl_overall"]) for r in rows if _matches(r, cell, m)]
            if kl:
                entry["methods"][m] = {"final_kl_overall": _stats(kl)}
        cells.append(entry)
    marginal = {}
    for name, values in spec.grid.items():
        marginal[name] = {
            m: {
                str(v): _stats(
                    [
                        float(r["final_kl_overall"])
                        for r in rows
                        if r["method"] == m and math.isclose(float(r[name]), float(v))
                    ]
                    or [math.nan]
                )
                for v in values
            }
            for m in spec.methods
        }
    return {
        "grid": {k: list(v) for k, v in spec.grid.items()},
        "methods": list(spec.methods),
        "seeds": list(range(spec.first_seed, spec.first_seed + spec.seeds)),
        "steps": spec.steps,
        "base": dict(spec.base),
        "runs": len(rows),
        "cells": cells,
        "by_parameter": marginal,
    }


def _matches(row: dict, cell: dict, method: str) -> bool:
    return row["method"] == method and all(
        math.isclose(float(row[k]), float(v)) for k, v in cell.items()
    )


def sensitivity_figure(spec: SweepSpec, rows: Sequence[dict], path: Path) -> None:
    """Final overall KL against each swept parameter, per method; one line per combination of
    the other parameters, the band the spread (one standard deviation) over seeds."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .figures import METHOD_LABELS

    names = list(spec.grid)
    fig, axes = plt.subplots(1, len(names), figsize=(6 * len(names), 4.5), squeeze=False)
    colors = plt.get_cmap("tab10")
    styles = ["-", "--", ":", "-."]
    for ax, name in zip(axes.flat, names, strict=True):
        others = {k: v for k, v in spec.grid.items() if k != name}
        combos = [
            dict(zip(others, vs, strict=True)) for vs in itertools.product(*others.values())
        ] or [{}]
        xs = np.array(spec.grid[name], dtype=float)
        for mi, m in enumerate(spec.methods):
            for ci, combo in enumerate(combos):
                stats = []
                for x in spec.grid[name]:
                    kl = [
                        float(r["final_kl_overall"])
                        for r in rows
                        if _matches(r, {**combo, name: x}, m)
                    ]
                    stats.append((np.mean(kl), np.std(kl)) if kl else (np.nan, np.nan))
                mean, std = np.array(stats).T
                label = METHOD_LABELS.get(m, m)
                if combo:
                    label += " (" + ", ".join(f"{k}={v:g}" for k, v in combo.items()) + ")"
                color = colors(mi % 10)
                ax.plot(xs, mean, styles[ci % 4], marker="o", color=color, label=label, lw=1.2)
                ax.fill_between(xs, mean - std, mean + std, color=color, alpha=0.12)
        if np.all(xs > 0) and xs.max() / xs.min() >= 10:
            ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(name)
        ax.set_ylabel("final KL(true || learned), mean of heights")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    fig.suptitle(
        f"Sensitivity after {spec.steps} steps: mean and spread over {spec.seeds} seeds",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
