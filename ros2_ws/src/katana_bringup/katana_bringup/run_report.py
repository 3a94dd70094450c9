"""Summary and figures of a robot run (simulated or real) from its experience log."""

from __future__ import annotations

import json
import os
import statistics
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from katana_curiosity.core.predictors import (  # noqa: E402
    ALPHA,
    THETA_ROBOT,
    PredictorBank,
    QueryRule,
)
from katana_curiosity.core.progress import (  # noqa: E402
    last_query,
    longest_identical_plan_streak,
    wasted_experiments,
)
from katana_curiosity.core.robot_loop import SETTING_CHANGES, robot_bank  # noqa: E402
from katana_curiosity.core.run_record import LOG_NAME, ExperienceLog, ExperimentRecord, replay  # noqa: E402


def summarise_run(records: list[ExperimentRecord], n_actions: int, max_height: int,
                  rule: QueryRule | None = None) -> dict:
    """Experiments, labels per height and action, the highest stack, seconds per experiment,
    and the attempts dropped on the way (by reason), over the whole logged run."""
    labels: dict[str, dict[str, dict[str, int]]] = {}
    for r in records:
        cell = labels.setdefault(str(r.state), {}).setdefault(
            str(r.action), {"stable": 0, "fell": 0}
        )
        cell["stable" if r.label > 0 else "fell"] += 1
    stable_heights = [r.state + 1 for r in records if r.label > 0]
    times = [r.wall_time for r in records]
    gaps = [b - a for a, b in zip(times, times[1:], strict=False) if b >= a]
    stage_names = sorted({k for r in records for k in r.stage_s})
    stages = {
        k: statistics.median([r.stage_s[k] for r in records if k in r.stage_s])
        for k in stage_names
    }
    dropped: Counter[str] = Counter()
    for r in records:
        dropped.update(r.dropped_before)
    modes = [r.mode for r in records]
    attempts = len(records) + sum(dropped.values())
    return {
        "experiments": len(records),
        "queries": modes.count("query"),
        "plans": modes.count("plan"),
        "heights_explored": sorted({int(r.state) for r in records}),
        "highest_stack": max(stable_heights, default=0),
        "labels": labels,
        "s_per_experiment": statistics.median(gaps) if gaps else None,
        "stage_median_s": stages,
        "dropped_experiments": {
            "total": sum(dropped.values()),
            "by_reason": dict(sorted(dropped.items())),
            "fraction_of_attempts": round(sum(dropped.values()) / attempts, 4) if attempts else 0.0,
        },
        "n_actions": n_actions,
        "max_height": max_height,
        **progress_figures(records, rule or QueryRule(ALPHA, THETA_ROBOT)),
    }


def progress_figures(records: list[ExperimentRecord], rule: QueryRule) -> dict:
    """Whether the run kept learning (core.progress): the experiments wasted (known, and on no
    way to an unknown pair), the longest streak of identical planned placements, the last
    query, and the setting changes made instead of plans, by reason."""
    wasted = wasted_experiments(records, rule)
    changes: Counter[str] = Counter()
    for r in records:
        changes.update({k: v for k, v in r.dropped_before.items() if k in SETTING_CHANGES})
    return {
        "wasted_experiments": {
            "total": len(wasted),
            "fraction": round(len(wasted) / len(records), 4) if records else 0.0,
            "indices": wasted,
        },
        "longest_identical_plan_streak": longest_identical_plan_streak(records),
        "last_query": last_query(records),
        "setting_changes_by_reason": dict(sorted(changes.items())),
    }


SESSIONS_NAME = "sessions.jsonl"


def append_session(run_dir: Path, session: dict) -> None:
    """Keep one session's figures (wall time, frames, judge agreement) beside the log, so the
    summary of a resumed run covers every session."""
    with open(Path(run_dir) / SESSIONS_NAME, "a", encoding="utf-8") as f:
        f.write(json.dumps(session, allow_nan=False) + "\n")


OPEN_SESSION_NAME = "session.open.json"


class SessionClock:
    """The running session's time kept on disk (rewritten atomically every `beat`), so a run
    killed mid-session still leaves its time: the next start closes it into sessions.jsonl
    (`close_killed_session`)."""

    def __init__(self, run_dir: Path, experiments_at_start: int) -> None:
        self.path = Path(run_dir) / OPEN_SESSION_NAME
        self.started = time.time()
        self._start = time.monotonic()
        self.beat(experiments_at_start)

    @property
    def wall_s(self) -> float:
        return time.monotonic() - self._start

    def beat(self, experiments: int) -> None:
        """Rewrite the open session; a failed write (disk full) only leaves the last one."""
        tmp = self.path.with_name(self.path.name + ".tmp")
        try:
            tmp.write_text(json.dumps({"started": round(self.started, 3),
                                       "wall_s": round(self.wall_s, 1),
                                       "experiments_at_end": experiments}))
            os.replace(tmp, self.path)
        except OSError:
            pass

    def close(self, session: dict) -> None:
        """This session ended (normally or by a signal): its record instead of the open one."""
        append_session(self.path.parent, {**session, "wall_s": round(self.wall_s, 1)})
        self.path.unlink(missing_ok=True)


def close_killed_session(run_dir: Path) -> dict | None:
    """A session left open by a killed run, closed into sessions.jsonl with the time and the
    experiments of its last beat; None if there was none."""
    path = Path(run_dir) / OPEN_SESSION_NAME
    try:
        open_session = json.loads(path.read_text(encoding="utf-8"))
        session = {"experiments_at_end": int(open_session["experiments_at_end"]),
                   "wall_s": float(open_session["wall_s"]), "completed": False, "killed": True}
    except FileNotFoundError:
        return None
    except (ValueError, KeyError, TypeError):  # torn by the kill itself: its time is unknown
        session = {"completed": False, "killed": True, "wall_s": 0.0}
    append_session(run_dir, session)
    path.unlink()
    return session


def read_sessions(run_dir: Path) -> list[dict]:
    path = Path(run_dir) / SESSIONS_NAME
    if not path.exists():
        return []
    sessions = []
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            sessions.append(json.loads(line))
        except json.JSONDecodeError:
            continue  # a torn line of a session figure; the log is the record of truth
    return sessions


def draw_margins(ax, margin: np.ndarray, chi: np.ndarray, counts: np.ndarray,
                 title: str) -> np.ndarray:
    """One height of a learned model (cf. Figure 13): the margin per action with its
    confidence band, and the experiments per action in grey (NaN: none written). Returns the
    actions (1-based) of the x axis."""
    actions = np.arange(1, len(margin) + 1)
    ax.fill_between(actions, margin - chi, margin + chi, color="lightsteelblue",
                    label="margin +- chi")
    ax.plot(actions, margin, "b.-", label="learned margin")
    for a, n in zip(actions, counts, strict=True):
        if np.isfinite(n):
            ax.annotate(str(int(n)), (a, -1.45), ha="center", fontsize=7, color="grey")
    ax.axhline(0, color="grey", lw=0.5)
    ax.set_xlim(0.5, len(margin) + 0.5)  # fixed: what is drawn on it later changes nothing
    ax.set_ylim(-1.6, 1.6)
    ax.set_xticks(actions)
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("action (bits on + 1)")
    return actions


def model_figure(bank: PredictorBank, max_height: int, counts: np.ndarray, path: Path) -> None:
    """Learned stability model per height and action with its confidence band (cf. Figure 13)."""
    heights = list(range(max_height + 1))
    fig, axes = plt.subplots(1, len(heights), figsize=(3.2 * len(heights), 3.4), squeeze=False)
    for ax, h in zip(axes[0], heights, strict=True):
        margin = bank.margin[h]
        actions = draw_margins(ax, margin, bank.chi[h], counts[h].astype(float),
                               f"height {h} ({int(bank.examples[bank.slot[h]])} experiments)")
        unknown = bank.unknown[h]
        ax.plot(actions[unknown], margin[unknown], "o", mfc="none", mec="orange", ms=10,
                label="still unknown")
    axes[0, 0].set_ylabel("margin (+1 stable, -1 falls)")
    axes[0, 0].legend(fontsize=7, loc="upper left")
    fig.suptitle("Learned placement models (grey: experiments per action)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def experience_figure(runs: Sequence[tuple[Sequence[str], Sequence[int]]], max_height: int,
                      path: Path, title: str = "") -> None:
    """Cumulative direct (query) and planned experience per height, the mean of `runs` (each
    its modes and states per experiment, cut to the shortest) (cf. Figure 4)."""
    n = min((len(modes) for modes, _ in runs), default=0)
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), sharey=True)
    x = np.arange(1, n + 1)
    for ax, mode in zip(axes, ("query", "plan"), strict=True):
        for h in range(max_height + 1):
            curves = np.array([np.cumsum([m == mode and s == h for m, s in
                                          zip(modes[:n], states[:n], strict=True)])
                               for modes, states in runs], dtype=float)
            mean = curves.mean(axis=0) if len(runs) else np.zeros(n)
            if n and mean[-1]:  # one colour per height in both panels
                ax.plot(x, mean, color=f"C{h}", label=f"height {h}")
        ax.set_title(("direct" if mode == "query" else "planned") + " exploration" + title,
                     fontsize=9)
        ax.set_xlabel("experiment")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("cumulative experience")
    lines = {label: line for ax in axes for line, label in zip(*ax.get_legend_handles_labels(),
                                                                 strict=True)}
    if lines:
        axes[0].legend([lines[k] for k in sorted(lines)], sorted(lines), fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_report(
    run_dir: Path,
    n_actions: int = 6,
    max_height: int = 3,
    alpha: float = ALPHA,
    theta: float = THETA_ROBOT,
    extra: dict | None = None,
) -> dict:
    """summary.json, model.png and experience.png in `run_dir`, from its experience log."""
    run_dir = Path(run_dir)
    records = ExperienceLog(run_dir / LOG_NAME).records
    bank = robot_bank(max_height, n_actions, alpha, theta)
    replay(bank, records, str(run_dir / LOG_NAME))
    summary = summarise_run(records, n_actions, max_height, bank.rule)
    summary.update(extra or {})
    counts = np.zeros((max_height + 2, n_actions), dtype=int)
    for r in records:
        counts[r.state, r.action_index] += 1
    model_figure(bank, max_height, counts, run_dir / "model.png")
    experience_figure([([r.mode for r in records], [r.state for r in records])], max_height,
                      run_dir / "experience.png")
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary
