"""The robot experiment measured (paper section 3.3): runs over seeds against the measured truth.

ROS-free. `analyse_run` replays one run's experience log through a fresh learner and reads, after
every experiment, the KL divergence per height from the measured truth (core.robot_truth), the
direct and planned experience per height, and which experiments were wasted, as the run's own
summary counts them (katana_curiosity.core.progress: known beforehand, came out as predicted,
and no experiment that taught the learner followed before a reset). `summarise` folds the runs
of each strategy into summary.json; the figure functions draw the paper's Figures 4/5 and 13
for the robot (katana_bringup.contact_sheet draws Figures 10-12).
"""

from __future__ import annotations

import csv
import statistics
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from katana_bringup import run_report  # noqa: E402
from katana_curiosity.core.predictors import (  # noqa: E402
    ALPHA,
    THETA_ROBOT,
    PredictorBank,
    QueryRule,
    one_hot_with_bias,
)
from katana_curiosity.core.progress import wasted_positions  # noqa: E402

from .claims.stats import MIN_SEEDS, mean_band  # noqa: E402
from .robot_truth import TruthTable, kl_to_truth, wilson_interval  # noqa: E402

#: the paper's claim of a usable model "within about 30 interactions" (section 3.3)
USABLE_AFTER = 30


@dataclass
class RunAnalysis:
    """One run replayed: per-experiment KL per height, experience counts and waste."""

    strategy: str
    seed: int
    kl: np.ndarray  # (experiments, heights) KL after each experiment; NaN where unmeasured
    states: np.ndarray  # height placed upon, per experiment
    actions: np.ndarray  # 1-based action, per experiment
    labels: np.ndarray  # +1 / -1
    modes: list[str]
    known_before: np.ndarray  # bool: the query condition called the pair known beforehand
    wasted: np.ndarray  # bool: core.progress's wasted experiment
    s_per_experiment: float | None
    final_margin: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 0)))
    final_chi: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 0)))

    @property
    def highest_stack(self) -> int:
        grown = self.states[self.labels > 0] + 1
        return int(grown.max()) if len(grown) else 0

    def actions_tried(self, n_actions: int, max_height: int) -> np.ndarray:
        counts = np.zeros((max_height + 1, n_actions), dtype=int)
        for s, a in zip(self.states, self.actions, strict=True):
            if 0 <= s <= max_height:
                counts[s, a - 1] += 1
        return counts


def analyse_run(
    records: Sequence,
    truth: TruthTable,
    strategy: str,
    seed: int,
    n_actions: int = 6,
    max_height: int = 3,
    alpha: float = ALPHA,
    theta: float = THETA_ROBOT,
) -> RunAnalysis:
    """Replay `records` (ExperimentRecord-like: state, action, label, mode, wall_time) in order
    through a fresh learner with the run's query rule, measuring after every update."""
    bank = PredictorBank(range(max_height + 1), one_hot_with_bias(n_actions),
                         QueryRule(alpha, theta), n_states=max_height + 2)
    heights = min(truth.n_states, max_height + 1)
    kl = np.full((len(records), heights), np.nan)
    known = np.zeros(len(records), dtype=bool)
    taught = np.zeros(len(records), dtype=bool)
    for i, r in enumerate(records):
        s, a, label = int(r.state), int(r.action), int(r.label)
        known[i] = not bool(bank.unknown[s, a - 1])
        taught[i] = not known[i] or label * bank.margin[s, a - 1] <= 0  # progress.taught
        bank.update(s, a - 1, float(label))
        for h, value in kl_to_truth(truth, bank.margin[:heights]).items():
            kl[i, h] = value
    wasted = np.zeros(len(records), dtype=bool)
    wasted[wasted_positions(taught, [int(getattr(r, "resets_before", 0)) for r in records])] = True
    times = [float(r.wall_time) for r in records if getattr(r, "wall_time", 0.0)]
    gaps = [b - a for a, b in zip(times, times[1:], strict=False) if b >= a]
    return RunAnalysis(
        strategy=strategy, seed=seed, kl=kl,
        states=np.array([int(r.state) for r in records], dtype=int),
        actions=np.array([int(r.action) for r in records], dtype=int),
        labels=np.array([int(r.label) for r in records], dtype=int),
        modes=[str(r.mode) for r in records], known_before=known, wasted=wasted,
        s_per_experiment=statistics.median(gaps) if gaps else None,
        final_margin=bank.margin.copy(), final_chi=bank.chi.copy(),
    )


def write_run_csv(analysis: RunAnalysis, path: Path) -> None:
    """One row per experiment: what was done, its outcome, and the KL per height after it."""
    heights = analysis.kl.shape[1]
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(["experiment", "mode", "state", "action", "label", "known_before",
                    "wasted", *(f"kl_h{h}" for h in range(heights)), "kl_overall"])
        for i in range(len(analysis.states)):
            row = analysis.kl[i]
            w.writerow([i, analysis.modes[i], int(analysis.states[i]), int(analysis.actions[i]),
                        int(analysis.labels[i]), int(analysis.known_before[i]),
                        int(analysis.wasted[i]),
                        *("" if np.isnan(v) else f"{v:.6g}" for v in row),
                        f"{np.nanmean(row):.6g}" if np.isfinite(row).any() else ""])


def _round(x: float | None, digits: int = 4) -> float | None:
    return None if x is None or not np.isfinite(x) else round(float(x), digits)


def summarise(
    analyses: Sequence[RunAnalysis],
    experiments: int,
    seeds: Sequence[int],
    truth_path: str,
    n_actions: int = 6,
    max_height: int = 3,
) -> dict:
    """summary.json of the robot experiment: per strategy the final KL per height and overall
    (means over the seeds), the actions tried per height (summed over the seeds), the highest
    stack (over the seeds), seconds per experiment (median of the runs' medians), and the
    wasted share."""
    strategies: dict[str, dict] = {}
    for strategy in dict.fromkeys(a.strategy for a in analyses):
        runs = [a for a in analyses if a.strategy == strategy]
        finals = np.array([r.kl[-1] if len(r.kl) else np.full(max_height + 1, np.nan)
                           for r in runs])
        heights = finals.shape[1]
        final_kl = {str(h): _round(np.nanmean(finals[:, h])) if np.isfinite(finals[:, h]).any()
                    else None for h in range(heights)}
        per_run_overall = [float(np.nanmean(f)) for f in finals if np.isfinite(f).any()]
        tried = sum(r.actions_tried(n_actions, max_height) for r in runs)
        at_usable = [float(np.nanmean(r.kl[USABLE_AFTER - 1])) for r in runs
                     if len(r.kl) >= USABLE_AFTER and np.isfinite(r.kl[USABLE_AFTER - 1]).any()]
        spe = [r.s_per_experiment for r in runs if r.s_per_experiment is not None]
        done = sum(len(r.states) for r in runs)
        wasted = sum(int(r.wasted.sum()) for r in runs)
        strategies[strategy] = {
            "final_kl": final_kl,
            "final_kl_overall": _round(statistics.mean(per_run_overall))
            if per_run_overall else None,
            "actions_tried": {str(h): {str(a + 1): int(tried[h, a]) for a in range(n_actions)}
                              for h in range(max_height + 1)},
            "highest_stack": max((r.highest_stack for r in runs), default=0),
            "s_per_experiment": _round(statistics.median(spe), 3) if spe else None,
            "wasted_share": _round(wasted / done) if done else None,
            "wasted_experiments": wasted,
            f"kl_overall_after_{USABLE_AFTER}": _round(statistics.mean(at_usable))
            if at_usable else None,
            "experiments_done": [len(r.states) for r in runs],
            "highest_stack_per_seed": [r.highest_stack for r in runs],
            "final_kl_overall_per_seed": [_round(v) for v in per_run_overall],
        }
    return {"experiments": experiments, "seeds": list(seeds), "truth": truth_path,
            "strategies": strategies}


# -- figures -------------------------------------------------------------------------------


def _curves(runs: Sequence[RunAnalysis], h: int | None) -> np.ndarray:
    """(seeds, experiments) KL at height `h`, or overall (the mean over the measured heights)
    with h None; cut to the shortest run."""
    n = min(len(r.kl) for r in runs)
    if h is not None:
        return np.array([r.kl[:n, h] for r in runs])
    with warnings.catch_warnings():  # experiments before any height was measured
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.array([np.nanmean(r.kl[:n], axis=1) for r in runs])


def kl_figure(analyses: Sequence[RunAnalysis], path: Path) -> None:
    """Learning curves: KL(measured truth || learned) per height and overall over experiments,
    one line per strategy, the mean over seeds with its 95 % bootstrap band (the range of the
    seeds with fewer than three) (cf. Figures 5 and 9)."""
    strategies = list(dict.fromkeys(a.strategy for a in analyses))
    heights = analyses[0].kl.shape[1]
    panels = [*range(heights), None]
    fig, axes = plt.subplots(1, len(panels), figsize=(3.3 * len(panels), 3.2), squeeze=False,
                             sharey=True)
    for h, ax in zip(panels, axes[0], strict=True):
        for k, strategy in enumerate(strategies):
            runs = [a for a in analyses if a.strategy == strategy and len(a.kl)]
            if not runs:
                continue
            mean, low, high = mean_band(_curves(runs, h))
            x = np.arange(1, len(mean) + 1)
            band = "95 % CI" if len(runs) >= MIN_SEEDS else "range"
            ax.plot(x, mean, color=f"C{k}", label=f"{strategy} ({len(runs)} seeds, {band})")
            ax.fill_between(x, low, high, color=f"C{k}", alpha=0.18, lw=0)
        ax.axvline(USABLE_AFTER, color="grey", lw=0.6, ls=":")
        ax.set_title("overall" if h is None else f"height {h}", fontsize=9)
        ax.set_xlabel("experiment")
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("KL(measured truth || learned)")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def experience_figure(analyses: Sequence[RunAnalysis], path: Path, strategy: str) -> None:
    """Cumulative direct (query) and planned experience per height, mean over the seeds of
    `strategy` (cf. Figure 4)."""
    runs = [a for a in analyses if a.strategy == strategy and len(a.states)]
    if not runs:
        return
    run_report.experience_figure([(r.modes, r.states) for r in runs], runs[0].kl.shape[1] - 1,
                                 path, f" ({strategy}, mean of {len(runs)} seeds)")


def model_figure(analysis: RunAnalysis, truth: TruthTable, path: Path) -> None:
    """The learned model of one run with its confidence band per height, the measured truth
    (as a margin 2p - 1, with its Wilson interval) beside it (cf. Figure 13)."""
    heights = analysis.kl.shape[1]
    n_actions = analysis.final_margin.shape[1]
    counts = analysis.actions_tried(n_actions, heights - 1)
    p = truth.p_stable()
    fig, axes = plt.subplots(1, heights, figsize=(3.2 * heights, 3.4), squeeze=False)
    for h, ax in enumerate(axes[0]):
        # pairs that cannot occur (on the table only action 1) are not drawn
        occurs = truth.possible[h] if h < truth.n_states else np.ones(n_actions, dtype=bool)
        run_report.draw_margins(ax, np.where(occurs, analysis.final_margin[h], np.nan),
                                np.where(occurs, analysis.final_chi[h], np.nan),
                                np.where(occurs, counts[h], np.nan), f"height {h}")
        labelled = False
        for a in range(n_actions):
            if not occurs[a]:
                ax.text(a + 1, 0.0, "cannot occur", ha="center", va="center", fontsize=6,
                        color="grey", rotation=90)
            elif h < truth.n_states and np.isfinite(p[h, a]):
                lo, hi = wilson_interval(int(truth.stayed[h, a]), int(truth.trials[h, a]))
                ax.errorbar(a + 1.12, 2 * p[h, a] - 1, yerr=[[2 * (p[h, a] - lo)],
                            [2 * (hi - p[h, a])]], fmt="s", color="k", ms=3, lw=0.8,
                            label=None if labelled else "measured truth (Wilson 95 %)")
                labelled = True
    axes[0, 0].set_ylabel("margin (+1 stays, -1 falls)")
    legend: dict = {}
    for ax in axes[0]:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            legend.setdefault(label, handle)
    fig.legend(list(legend.values()), list(legend), fontsize=7, loc="lower center", ncol=3)
    fig.suptitle(f"Learned model, {analysis.strategy} seed {analysis.seed}, after "
                 f"{len(analysis.states)} experiments (grey: experiments per action)",
                 fontsize=10)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def truth_figure(truth: TruthTable, path: Path) -> None:
    """Measured P(stays) per height and action with Wilson 95 % intervals; impossible pairs
    marked as such."""
    p = truth.p_stable()
    fig, axes = plt.subplots(1, truth.n_states, figsize=(3.0 * truth.n_states, 3.0),
                             squeeze=False, sharey=True)
    actions = np.arange(1, truth.n_actions + 1)
    for h, ax in enumerate(axes[0]):
        for a in range(truth.n_actions):
            if not truth.possible[h, a]:
                ax.text(a + 1, 0.5, "cannot\noccur", ha="center", va="center", fontsize=6,
                        color="grey", rotation=90)
                continue
            n, k = int(truth.trials[h, a]), int(truth.stayed[h, a])
            if n == 0:
                ax.text(a + 1, 0.5, "not\nmeasured", ha="center", va="center", fontsize=6,
                        color="tab:orange", rotation=90)
                continue
            lo, hi = wilson_interval(k, n)
            ax.bar(a + 1, p[h, a], color="tab:green", alpha=0.6)
            ax.errorbar(a + 1, p[h, a], yerr=[[p[h, a] - lo], [hi - p[h, a]]], color="k",
                        capsize=2, lw=0.8)
            ax.annotate(f"{k}/{n}", (a + 1, 1.04), ha="center", fontsize=6)
        ax.set_ylim(0, 1.12)
        ax.set_xticks(actions)
        ax.set_title(f"height {h}", fontsize=9)
        ax.set_xlabel("action (bits on + 1)")
    axes[0, 0].set_ylabel("P(block stays), Wilson 95 %")
    fig.suptitle("Measured ground truth of the simulated world", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
