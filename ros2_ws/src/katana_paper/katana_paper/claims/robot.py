"""The claims of section 3.3 (the robot), from a `katana-robot paper` run folder: every run's
experience log (runs/<strategy>-s<seed>/experience.jsonl) replayed into a fresh learner
(core.run_record.replay into core.robot_loop.robot_bank) and measured against the measured
truth (robot_truth.kl_to_truth), so that no claim depends on a summary field."""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from katana_curiosity.core.predictors import ALPHA, THETA_ROBOT
from katana_curiosity.core.robot_loop import robot_bank
from katana_curiosity.core.run_record import CHECKPOINT_NAME, LOG_NAME, ExperienceLog, replay

from ..robot_truth import TruthTable, kl_to_truth
from . import stats
from .abstract import rank_correlation
from .core import DEFAULT_SETTINGS, ClaimSpec, RunNaming, Settings, document, evaluate

#: a run's folder name, as robot_runs.run_name writes it
RUN_NAME = RunNaming("{strategy}-s{seed}",
                     re.compile(r"(?P<strategy>.+)-s(?P<seed>[0-9]+)", re.DOTALL))
run_name, parse_run_name = RUN_NAME.name, RUN_NAME.parse
#: the experiment counts at which Q1 and Random are compared ("as far as the runs go")
CHECKPOINTS = (15, 30, 60, 120)
#: the paper's "single run with 30 interactions" (Figure 13); as robot_paper.USABLE_AFTER
USABLE_AFTER = 30
#: a usable model: its overall KL to the truth at most this share of the untrained model's
USABLE_SHARE = 0.5
#: the band of P(stays) in the measured truth that makes a pair's outcome uncertain (the
#: pages' `uncertain_pairs` use the same)
UNCERTAIN = (0.05, 0.95)


@dataclass
class RobotRun:
    """One run folder: its records and the query rule its learner checkpoint records."""

    strategy: str
    seed: int
    records: list = field(repr=False)
    alpha: float | None = None
    theta: float | None = None


def _rule(run: Path) -> tuple[float | None, float | None]:
    """alpha and theta of the run's learner.npz, or None where it has none."""
    path = run / CHECKPOINT_NAME
    if not path.exists():
        return None, None
    with np.load(path, allow_pickle=False) as data:
        return (float(data["alpha"]) if "alpha" in data.files else None,
                float(data["theta"]) if "theta" in data.files else None)


def load_folder(run_dir: Path) -> tuple[dict | None, list[RobotRun]]:
    """summary.json (None if absent) and every run under run_dir/runs whose folder is named
    <strategy>-s<seed> and holds an experience log. ValueError when there is none; a log's
    own errors (core.run_record.LogError, a ValueError) name the file and line."""
    run_dir = Path(run_dir)
    summary_path = run_dir / "summary.json"
    summary = json.loads(summary_path.read_text(encoding="utf-8")) \
        if summary_path.exists() else None
    runs = []
    for folder in sorted(p for p in (run_dir / "runs").glob("*") if p.is_dir()):
        parsed = parse_run_name(folder.name)
        if parsed is None or not (folder / LOG_NAME).exists():
            continue
        records = ExperienceLog(folder / LOG_NAME).records
        runs.append(RobotRun(parsed[0], parsed[1], records, *_rule(folder)))
    if not runs:
        raise ValueError(f"{run_dir}: no runs/<strategy>-s<seed>/{LOG_NAME} (a `katana-robot "
                         "paper` output folder?)")
    runs.sort(key=lambda r: (r.strategy, r.seed))
    return summary, runs


# -- per-seed values -----------------------------------------------------------------------


def overall_kl(truth: TruthTable, margin: np.ndarray) -> float:
    """KL(measured truth || model) averaged over the measured heights."""
    return float(np.mean(list(kl_to_truth(truth, margin).values())))


def untrained_kl(truth: TruthTable) -> float:
    """The overall KL of a learner that has seen nothing (every margin 0, P = 1/2)."""
    return overall_kl(truth, np.zeros((truth.n_states, truth.n_actions)))


def kl_after(records: Sequence, truth: TruthTable, checkpoints: Iterable[int],
             alpha: float = ALPHA, theta: float = THETA_ROBOT) -> dict[int, float]:
    """The overall KL to the truth after each checkpoint's first experiments, the log replayed
    in order into one fresh robot learner; NaN where the run ends before a checkpoint."""
    heights = max([truth.n_states - 1, *(int(r.state) for r in records)])
    bank = robot_bank(heights, truth.n_actions, alpha, theta)
    out, done = {}, 0
    for k in sorted(set(checkpoints)):
        if k > len(records):
            out[k] = math.nan
            continue
        done += replay(bank, records[done:k], "experience log")
        out[k] = overall_kl(truth, bank.margin)
    return out


def uncertain_pairs(truth: TruthTable, band: tuple[float, float] = UNCERTAIN
                    ) -> set[tuple[int, int]]:
    """(height, 1-based action) of the measured pairs with band[0] < P(stays) < band[1]."""
    p = truth.p_stable()
    return {(h, a + 1) for h in range(truth.n_states) for a in range(truth.n_actions)
            if np.isfinite(p[h, a]) and band[0] < p[h, a] < band[1]}


def at_heights_of(records: Sequence, pairs: set[tuple[int, int]]) -> list:
    """The exploring placements (every one but a plan's) made at the heights `pairs` lie at."""
    heights = {h for h, _ in pairs}
    return [r for r in records if int(r.state) in heights and r.mode != "plan"]


def share_on(records: Sequence, pairs: set[tuple[int, int]]) -> float:
    """Share of `pairs` among the exploring placements made at their heights (Q1's queries,
    all of Random's). The paper's attention is where exploration goes among the actions of one
    height ("it now focuses on exploring height two"; Figure 6: the uncertain features "stay
    interesting longer"): which heights a strategy places at is the stages' claim, and a plan's
    placement serves the plan, not the exploration. NaN without such placements."""
    at = at_heights_of(records, pairs)
    if not at:
        return math.nan
    return float(np.mean([(int(r.state), int(r.action)) in pairs for r in at]))


def shift_towards(records: Sequence, pairs: set[tuple[int, int]]) -> float:
    """Of the exploring placements at the heights of `pairs`: the second half's share on
    `pairs` minus the first half's; NaN with fewer than two."""
    at = at_heights_of(records, pairs)
    if len(at) < 2:
        return math.nan
    half = len(at) // 2
    return share_on(at[half:], pairs) - share_on(at[:half], pairs)


def _indices(records: Sequence, mode: str) -> dict[int, list[int]]:
    out: dict[int, list[int]] = {}
    for i, r in enumerate(records):
        if r.mode == mode:
            out.setdefault(int(r.state), []).append(i)
    return out


def stage_order(records: Sequence) -> float:
    """Spearman's rho between height and the median experiment of its direct (query)
    placements: > 0 when heights are explored in order; NaN with fewer than two heights."""
    direct = _indices(records, "query")
    heights = sorted(direct)
    return rank_correlation(heights, [float(np.median(direct[h])) for h in heights])


def direct_then_planned(records: Sequence) -> float:
    """Mean over the heights with both direct and planned placements of (median planned
    experiment - median direct experiment) / experiments: > 0 when a height is explored
    directly before it is planned upon; NaN without such a height."""
    direct, planned = _indices(records, "query"), _indices(records, "plan")
    both = sorted(set(direct) & set(planned))
    if not both:
        return math.nan
    return float(np.mean([(np.median(planned[h]) - np.median(direct[h])) / len(records)
                          for h in both]))


@dataclass
class SeedValues:
    """What the claims read of one run."""

    strategy: str
    seed: int
    experiments: int
    kl_after: dict[int, float]
    uncertain_share: float
    uncertain_shift: float
    stage_order: float
    direct_then_planned: float


def seed_values(run: RobotRun, truth: TruthTable, checkpoints: Iterable[int],
                pairs: set[tuple[int, int]]) -> SeedValues:
    r = run.records
    return SeedValues(run.strategy, run.seed, len(r),
                      kl_after(r, truth, checkpoints, run.alpha or ALPHA,
                               run.theta or THETA_ROBOT),
                      share_on(r, pairs), shift_towards(r, pairs), stage_order(r),
                      direct_then_planned(r))


# -- the claims ----------------------------------------------------------------------------

S33 = "section 3.3"
ATTENTION = ("we find that the robot gradually shifted its attention ... to trying actions A3 "
             "and A4 ..., which are actually the actions with the most uncertain placement "
             "outcomes among the six actions")


def section_33(values: Sequence[SeedValues], truth: TruthTable, pairs: set[tuple[int, int]],
               band: tuple[float, float] = UNCERTAIN, settings: Settings = DEFAULT_SETTINGS,
               thetas: Sequence[float] = ()) -> tuple[list[dict], list[dict]]:
    """Every claim of section 3.3 the runs decide, and the ones they cannot."""
    out: list[dict] = []
    not_evaluated: list[dict] = []

    def groups(strategies: Sequence[str], value) -> dict[str, dict[int, float]]:
        return {s: {v.seed: value(v) for v in values if v.strategy == s} for s in strategies}

    def claim(spec: ClaimSpec, strategies, value, statistic, note: str = "") -> None:
        out.append(evaluate(spec, groups(strategies, value), statistic, settings, note))

    pair_text = ", ".join(f"({h}, a{a})" for h, a in sorted(pairs))
    if pairs:
        claim(ClaimSpec("attention-on-uncertain-pairs", f"{S33}, Figures 10-12", ATTENTION,
                        f"of the exploring placements (Q1's queries, all of Random's) at the "
                        f"heights of the truth's uncertain pairs ({band[0]:g} < P(stays) < "
                        f"{band[1]:g}: {pair_text}), the share on those pairs: Q1's minus "
                        f"Random's",
                        stats.Claimed("greater")),
              ("q1", "random"), lambda v: v.uncertain_share, stats.difference)
        claim(ClaimSpec("attention-shifts-to-uncertain-pairs", f"{S33}, Figures 10-12",
                        ATTENTION,
                        "of Q1's queries at the heights of the uncertain pairs, the share on "
                        "those pairs in the second half minus that in the first, per seed",
                        stats.Claimed("greater")),
              ("q1",), lambda v: v.uncertain_shift, stats.mean)
    else:
        not_evaluated.append({
            "id": "attention-on-uncertain-pairs", "where": f"{S33}, Figures 10-12",
            "paper": ATTENTION,
            "why": f"the measured truth has no pair with {band[0]:g} < P(stays) < {band[1]:g}"})
    threshold = USABLE_SHARE * untrained_kl(truth)
    odd = sorted({t for t in thetas if t is not None and not math.isclose(t, THETA_ROBOT)})
    claim(ClaimSpec("usable-model-after-30", f"{S33}, Figure 13",
                    "Figure 13 shows the predictive models the Katana robot arm acquired in a "
                    "single run with 30 interactions",
                    f"Q1's overall KL to the measured truth after {USABLE_AFTER} experiments "
                    f"(mean over the measured heights); usable taken as at most "
                    f"{USABLE_SHARE:g} x the untrained model's ({untrained_kl(truth):.3g}), "
                    f"i.e. below {threshold:.3g}", stats.Claimed("less", threshold), "nats"),
          ("q1",), lambda v: v.kl_after.get(USABLE_AFTER, math.nan), stats.mean,
          note=(f"the runs were made at theta {', '.join(f'{t:g}' for t in odd)}, not the "
                f"paper's {THETA_ROBOT:g}") if odd else "")
    longest = max((v.experiments for v in values), default=0)
    for k in CHECKPOINTS:
        if k > longest:
            not_evaluated.append({
                "id": f"q1-faster-than-random-after-{k}", "where": f"{S33} (3.2's claim)",
                "paper": "making much slower progress than Q1 and Q10",
                "why": f"the runs end before {k} experiments (longest {longest})"})
            continue
        claim(ClaimSpec(f"q1-faster-than-random-after-{k}", f"{S33}, with section 3.2's claim",
                        "The random method, on the other hand, though making much slower "
                        "progress than Q1 and Q10 in the first 1000 timesteps",
                        f"Random's overall KL to the measured truth after {k} experiments minus "
                        "Q1's (runs that reached it)", stats.Claimed("greater"), "nats"),
              ("random", "q1"), lambda v, k=k: v.kl_after.get(k, math.nan), stats.difference)
    claim(ClaimSpec("robot-stages-in-order", f"{S33}, with section 3.2's Figure 4",
                    "Since the robot has already had some prior experience ..., it now focuses "
                    "on exploring height two; [section 3.2:] easier problems ... are learned "
                    "first, and more difficult problems are learned later",
                    "Spearman's rho, per Q1 seed, between height and the median experiment of "
                    "its direct (query) placements", stats.Claimed("greater")),
          ("q1",), lambda v: v.stage_order, stats.mean)
    claim(ClaimSpec("robot-direct-then-planned", f"{S33}, with section 3.2's Figure 4",
                    "the learner switches from direct exploration of one height to planning "
                    "exploration of higher heights",
                    "per Q1 seed, the mean over heights with both of (median planned "
                    "experiment - median direct experiment) / experiments",
                    stats.Claimed("greater")),
          ("q1",), lambda v: v.direct_then_planned, stats.mean)
    return out, not_evaluated


def claims_document(run_dir: Path, truth_path: Path, settings: Settings = DEFAULT_SETTINGS,
                    band: tuple[float, float] = UNCERTAIN, command: str = "",
                    loaded: tuple[dict | None, list[RobotRun]] | None = None) -> dict:
    """claims.json of a `katana-robot paper` run folder against the truth at `truth_path`
    (`loaded`: what load_folder(run_dir) gave, if it was read already)."""
    summary, runs = loaded or load_folder(run_dir)
    truth = TruthTable.load(truth_path)
    pairs = uncertain_pairs(truth, band)
    checkpoints = sorted({*CHECKPOINTS, USABLE_AFTER})
    values = [seed_values(r, truth, checkpoints, pairs) for r in runs]
    claims, not_evaluated = section_33(values, truth, pairs, band, settings,
                                       [r.theta for r in runs])
    seeds = {s: sorted(r.seed for r in runs if r.strategy == s)
             for s in dict.fromkeys(r.strategy for r in runs)}
    context = {
        "experiments": (summary or {}).get("experiments"),
        "experiments_done": {run_name(v.strategy, v.seed): v.experiments for v in values},
        "seeds": seeds, "truth": str(truth_path),
        "uncertain_pairs": [list(p) for p in sorted(pairs)], "uncertain_band": list(band),
        "thetas": sorted({r.theta for r in runs if r.theta is not None}),
        "kl_after": {run_name(v.strategy, v.seed): {str(k): (None if not math.isfinite(x)
                                                             else round(x, 6))
                                                    for k, x in v.kl_after.items()}
                     for v in values},
    }
    return document("3.3", str(run_dir), command or f"katana-robot claims {run_dir}",
                    claims, not_evaluated, settings, **context)
