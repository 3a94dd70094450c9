"""Figures 4-9 of the paper from experiment results, and the sensitivity of a sweep
(matplotlib, headless)."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from katana_curiosity.core.explorer import PLAN, QUERY  # noqa: E402

from .experiments import RunResult  # noqa: E402
from .metrics import experience_histogram  # noqa: E402
from .processes import worker_context  # noqa: E402
from .sweep import SweepSpec, matches  # noqa: E402

STRATEGY_LABELS = {
    "q1": "Q1",
    "q10": "Q10",
    "conf": "Conf",
    "random": "Random",
    "lp": "LP",
    "variance": "Variance",
    "rmax": "R-max",
    "egreedy": "eps-greedy",
}


def _fixed_layout(fig, left: float, right: float, hspace: float, wspace: float) -> None:
    """Margins for a title on top and tick labels below; tight_layout would draw the figure
    once more just to measure it (a third of a figure's time)."""
    height_in = fig.get_figheight()
    fig.subplots_adjust(
        left=left,
        right=right,
        top=1.0 - 0.5 / height_in,
        bottom=0.45 / height_in,
        hspace=hspace,
        wspace=wspace,
    )


def _colors(n: int) -> list:
    return [plt.get_cmap("viridis")(i / max(n - 1, 1)) for i in range(n)]


def _runs(results: Sequence[RunResult], strategy: str) -> list[RunResult]:
    return [r for r in results if r.config.strategy == strategy]


def figure4(results: Sequence[RunResult], path: Path, strategy: str = "q1") -> None:
    """Cumulative direct and planned experience per height (mean over seeds), Figure 4."""
    runs = _runs(results, strategy)
    at = runs[0].record_at
    direct = np.mean([r.cumulative(QUERY) for r in runs], axis=0)
    planned = np.mean([r.cumulative(PLAN) for r in runs], axis=0)
    n_states = runs[0].n_states - 1
    colors = _colors(n_states)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), sharey=True)
    for s in range(n_states):
        if direct[-1, s] > 0:
            axes[0].plot(at, direct[:, s], color=colors[s], label=f"height {s}")
        if planned[-1, s] > 0:
            axes[1].plot(at, planned[:, s], color=colors[s], label=f"height {s}")
    first = runs[0]
    for s in range(1, n_states):
        hits = np.flatnonzero((first.states == s) & (first.modes == QUERY))
        if len(hits):
            for ax in axes:
                ax.axvline(hits[-1] + 1, color=colors[s], lw=0.8, ls=":")
    axes[0].set_title(f"Direct exploration ({STRATEGY_LABELS.get(strategy, strategy)})")
    axes[1].set_title("Planned exploration")
    for ax in axes:
        ax.set_xlabel("experiment")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(f"cumulative experience (mean of {len(runs)} runs)")
    # one legend (the heights' colours are shared): on the planned panel, or on the direct one
    # while nothing was planned (short runs, a strategy that never plans)
    labelled = [ax for ax in (axes[1], axes[0]) if ax.get_legend_handles_labels()[0]]
    if axes[1] not in labelled:
        axes[1].text(0.5, 0.5, "no planned experiments", transform=axes[1].transAxes,
                     ha="center", va="center", color="0.4")
    if labelled:
        labelled[0].legend(fontsize=8, loc="upper left")
    fig.suptitle(
        "Figure 4: developmental stages; dotted lines: end of direct exploration "
        f"per height in run seed={first.config.seed}",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def figure5(results: Sequence[RunResult], path: Path, strategy: str = "q1") -> None:
    """KL divergence between learned and true models per height over experiments, Figure 5."""
    runs = _runs(results, strategy)
    at = runs[0].record_at
    kl = np.mean([r.kl for r in runs], axis=0)
    heights = runs[0].heights
    colors = _colors(len(heights) + 1)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for i, h in enumerate(heights):
        ax.plot(at, kl[:, i], color=colors[h], label=f"height {h}")
    ax.set_yscale("log")
    ax.set_xlabel("experiment")
    ax.set_ylabel("KL(true || learned), mean over features")
    ax.set_title(
        f"Figure 5: learning progress ({STRATEGY_LABELS.get(strategy, strategy)}, "
        f"mean of {len(runs)} runs)"
    )
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _focus_row(ax_hist, ax_model, result: RunResult, state: int, snap: int) -> None:
    n_actions = result.true_margin.shape[1]
    upto = int(result.snapshot_at[snap])
    counts = experience_histogram(
        result.states.astype(int), result.actions.astype(int), state, n_actions, upto
    )
    idx = np.arange(1, n_actions + 1)
    unknown = np.flatnonzero(result.snapshot_unknown[snap, state])
    for ax in (ax_hist, ax_model):
        if len(unknown):
            ax.axvspan(unknown.min() + 0.5, unknown.max() + 1.5, color="orange", alpha=0.2)
            ax.axvline(unknown.min() + 0.5, color="orange", lw=0.8)
            ax.axvline(unknown.max() + 1.5, color="orange", lw=0.8)
    ax_hist.bar(idx, counts, color="steelblue")
    ax_hist.set_ylabel(f"t={upto}\nexperience", fontsize=8)
    margin = result.snapshot_margin[snap, state]
    chi = result.snapshot_chi[snap, state]
    ax_model.plot(idx, result.true_margin[state], "r-", lw=1.2, label="true margin")
    ax_model.plot(idx, margin, "b--", lw=1.2, label="learned margin")
    ax_model.plot(idx, margin + chi, "k-", lw=0.5, label="margin +- chi")
    ax_model.plot(idx, margin - chi, "k-", lw=0.5)
    ax_model.axhline(0, color="grey", lw=0.5)
    ax_model.set_ylim(-1.6, 1.6)
    for ax in (ax_hist, ax_model):
        ax.set_xlim(0.5, n_actions + 0.5)
        ax.tick_params(labelsize=7)


def focus_figure(
    result: RunResult, state: int, path: Path, snaps: Sequence[int] | None = None, title: str = ""
) -> None:
    """Exploration focus at one height (Figures 6 and 7): experience and model over time."""
    snaps = list(range(len(result.snapshot_at))) if snaps is None else list(snaps)
    fig, axes = plt.subplots(len(snaps), 2, figsize=(10, 1.9 * len(snaps) + 0.8), squeeze=False)
    for row, snap in enumerate(snaps):
        _focus_row(axes[row, 0], axes[row, 1], result, state, snap)
    axes[0, 1].legend(fontsize=7, loc="upper left")
    axes[-1, 0].set_xlabel("feature index (ascending stability)")
    axes[-1, 1].set_xlabel("feature index (ascending stability)")
    fig.suptitle(
        title or f"Exploration focus at height {state}; shaded: still unknown", fontsize=10
    )
    _fixed_layout(fig, left=0.08, right=0.98, hspace=0.3, wspace=0.15)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def figure8(result: RunResult, path: Path, heights: Sequence[int] = (1, 2, 3, 4, 5, 6)) -> None:
    """Exploration focus of the first six heights at the end of the run (Figure 8)."""
    last = len(result.snapshot_at) - 1
    fig, axes = plt.subplots(len(heights), 2, figsize=(10, 1.9 * len(heights) + 0.8), squeeze=False)
    for row, h in enumerate(heights):
        _focus_row(axes[row, 0], axes[row, 1], result, h, last)
        axes[row, 0].set_ylabel(f"height {h}\nexperience", fontsize=8)
    axes[0, 1].legend(fontsize=7, loc="upper left")
    axes[-1, 0].set_xlabel("feature index (ascending stability)")
    axes[-1, 1].set_xlabel("feature index (ascending stability)")
    fig.suptitle(
        f"Figure 8: heights 1-6 at t={int(result.snapshot_at[last])} "
        f"(run seed={result.config.seed}); shaded: still unknown",
        fontsize=10,
    )
    _fixed_layout(fig, left=0.08, right=0.98, hspace=0.3, wspace=0.15)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def figure9(results: Sequence[RunResult], path: Path) -> None:
    """KL per height and overall for every strategy (Figure 9)."""
    strategies = list(dict.fromkeys(r.config.strategy for r in results))
    heights = results[0].heights
    at = results[0].record_at
    n = len(heights) + 1
    cols = 4
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(14, 3.2 * rows), squeeze=False)
    for m in strategies:
        runs = _runs(results, m)
        kl = np.mean([r.kl for r in runs], axis=0)
        for i in range(len(heights)):
            axes.flat[i].plot(at, kl[:, i], label=STRATEGY_LABELS.get(m, m))
        axes.flat[len(heights)].plot(at, kl.mean(axis=1), label=STRATEGY_LABELS.get(m, m))
    for i, h in enumerate(heights):
        axes.flat[i].set_title(f"height {h}", fontsize=9)
    axes.flat[len(heights)].set_title("overall (mean of heights)", fontsize=9)
    for ax in axes.flat[:n]:
        ax.set_yscale("log")
        ax.grid(alpha=0.3, which="both")
        ax.tick_params(which="both", labelsize=7)
    for ax in axes.flat[n:]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=8)
    seeds = len(_runs(results, strategies[0]))
    fig.suptitle(
        f"Figure 9: KL(true || learned) over experiments, mean of {seeds} runs", fontsize=10
    )
    _fixed_layout(fig, left=0.04, right=0.99, hspace=0.3, wspace=0.18)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _figure_tasks(results: Sequence[RunResult], out: Path) -> list[tuple[float, Callable]]:
    """(relative cost, draw) for fig4..fig9; figures 4-8 use Q1 when it was run."""
    strategies = list(dict.fromkeys(r.config.strategy for r in results))
    main = "q1" if "q1" in strategies else strategies[0]
    first = _runs(results, main)[0]
    early = [i for i, s in enumerate(first.snapshot_at) if s < first.config.experiments] or [0]

    def focus(height: int, number: int) -> Callable[[], None]:
        return lambda: focus_figure(
            first,
            height,
            out / f"fig{number}.png",
            early,
            f"Figure {number}: exploration focus at height {height} "
            f"(run seed={first.config.seed}); shaded: still unknown",
        )

    heights8 = [h for h in (1, 2, 3, 4, 5, 6) if h < first.n_states - 1]
    return [
        (1.0, lambda: figure4(results, out / "fig4.png", main)),
        (1.2, lambda: figure5(results, out / "fig5.png", main)),
        (2.5, focus(1, 6)),
        (2.5, focus(2, 7)),
        (3.0, lambda: figure8(first, out / "fig8.png", heights8)),
        (3.2, lambda: figure9(results, out / "fig9.png")),
    ]


def _draw_group(results: Sequence[RunResult], out: Path, indices: list[int]) -> None:
    tasks = _figure_tasks(results, out)
    for i in indices:
        tasks[i][1]()


def paper_figures(results: Sequence[RunResult], out: Path, jobs: int = 1) -> list[Path]:
    """Write fig4..fig9 for the results into `out`, in `jobs` processes (figures are
    independent; each worker is handed the results and draws its share)."""
    tasks = _figure_tasks(results, out)
    jobs = max(1, min(jobs, len(tasks)))
    if jobs == 1:
        for _, draw in tasks:
            draw()
    else:
        # Longest first onto the least loaded group.
        groups: list[list[int]] = [[] for _ in range(jobs)]
        loads = [0.0] * jobs
        for i in sorted(range(len(tasks)), key=lambda i: -tasks[i][0]):
            g = loads.index(min(loads))
            groups[g].append(i)
            loads[g] += tasks[i][0]
        with ProcessPoolExecutor(max_workers=jobs, mp_context=worker_context()) as pool:
            for future in [pool.submit(_draw_group, list(results), out, g) for g in groups]:
                future.result()
    return [out / f"fig{i}.png" for i in range(4, 10)]


def sensitivity_figure(spec: SweepSpec, rows: Sequence[dict], path: Path) -> None:
    """Final overall KL against each swept parameter, per strategy; one line per combination of
    the other parameters, the band the spread (one standard deviation) over seeds."""
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
        for mi, m in enumerate(spec.strategies):
            for ci, combo in enumerate(combos):
                stats = []
                for x in spec.grid[name]:
                    kl = [
                        float(r["final_kl_overall"])
                        for r in rows
                        if matches(r, {**combo, name: x}, m)
                    ]
                    stats.append((np.mean(kl), np.std(kl)) if kl else (np.nan, np.nan))
                mean, std = np.array(stats).T
                label = STRATEGY_LABELS.get(m, m)
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
        f"Sensitivity after {spec.experiments} experiments: mean and spread over "
        f"{spec.seeds} seeds",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
