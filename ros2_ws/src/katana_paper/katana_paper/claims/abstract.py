"""The claims of section 3.2 (the simulated blocks world), from a `katana-curiosity paper` run
folder: its summary.json and one CSV per run (runs/<strategy>_seed<k>.csv, a row every
`record_every` experiments: KL per height and overall, cumulative direct and planned
experience per height). Every per-seed value is read from the CSVs, none from the summary's
means."""

from __future__ import annotations

import csv
import json
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy import stats as sps

from . import stats
from .core import DEFAULT_SETTINGS, ClaimSpec, RunNaming, Settings, document, evaluate

#: a run's CSV file name, as experiments.save_results gives it
RUN_CSV = RunNaming("{strategy}_seed{seed}.csv",
                    re.compile(r"(?P<strategy>[A-Za-z0-9]+)_seed(?P<seed>[0-9]+)\.csv"))
csv_name, parse_csv_name = RUN_CSV.name, RUN_CSV.parse
PAPER_STRATEGIES = ("q1", "q10", "conf", "random")
#: the early stage of Figure 9 ("in the first 1000 timesteps")
EARLY = 1000
#: share of Q1's whole KL decrease at heights 1-2 that "gets close ... then saturates" asks
#: for by step EARLY
SATURATED_SHARE = 0.8
#: "closely followed by Q10": Q10's final overall KL within this relative margin of Q1's
CLOSE_MARGIN = 0.10


@dataclass
class AbstractRun:
    """One run's CSV: the experiment counts of its rows and, per row, the KL per learned
    height and overall and the cumulative direct and planned experience per height."""

    strategy: str
    seed: int
    experiment: np.ndarray
    kl: dict[int, np.ndarray] = field(default_factory=dict)
    kl_overall: np.ndarray = field(default_factory=lambda: np.zeros(0))
    direct: dict[int, np.ndarray] = field(default_factory=dict)
    planned: dict[int, np.ndarray] = field(default_factory=dict)

    @property
    def heights(self) -> list[int]:
        return sorted(self.kl)

    def at(self, series: np.ndarray, experiments: int) -> float:
        """The value of a series at the last row with at most `experiments` done; NaN when
        the run ends before."""
        if experiments > self.experiment[-1]:
            return math.nan
        return float(series[np.searchsorted(self.experiment, experiments, side="right") - 1])


def read_run_csv(path: Path) -> AbstractRun:
    """Parse a run CSV; ValueError naming the file and line for anything malformed."""
    path = Path(path)
    parsed = parse_csv_name(path.name)
    if parsed is None:
        raise ValueError(f"{path}: not a run CSV name (<strategy>_seed<k>.csv)")
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    if not rows:
        raise ValueError(f"{path}: empty")
    header = rows[0]
    groups: dict[str, dict[int, int]] = {"kl": {}, "direct": {}, "planned": {}}
    for i, name in enumerate(header):
        m = re.fullmatch(r"(kl|direct|planned)_(\d+)", name)
        if m:
            groups[m[1]][int(m[2])] = i
    if "experiment" not in header or "kl_overall" not in header or not groups["kl"]:
        raise ValueError(f"{path}:1: needs the columns experiment, kl_<height>, kl_overall")
    if len(rows) < 2:
        raise ValueError(f"{path}: no rows")
    try:
        table = np.array([[float(v) for v in row] for row in rows[1:]])
    except ValueError:
        bad = next(n for n, row in enumerate(rows[1:], 2)
                   if not all(_is_float(v) for v in row))
        raise ValueError(f"{path}:{bad}: not a row of numbers") from None
    if table.ndim != 2 or table.shape[1] != len(header):
        raise ValueError(f"{path}: rows do not all have the header's {len(header)} columns")
    experiment = table[:, header.index("experiment")]
    if np.any(np.diff(experiment) <= 0):
        raise ValueError(f"{path}: the experiment column is not increasing")

    def cols(kind: str) -> dict[int, np.ndarray]:
        return {k: table[:, i] for k, i in sorted(groups[kind].items())}

    return AbstractRun(parsed[0], parsed[1], experiment, cols("kl"),
                       table[:, header.index("kl_overall")], cols("direct"), cols("planned"))


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def load_folder(run_dir: Path) -> tuple[dict | None, list[AbstractRun]]:
    """summary.json (None if absent) and every run CSV under run_dir/runs, by strategy and
    seed. ValueError when the folder holds no run CSV."""
    run_dir = Path(run_dir)
    summary_path = run_dir / "summary.json"
    summary = json.loads(summary_path.read_text(encoding="utf-8")) \
        if summary_path.exists() else None
    files = sorted(p for p in (run_dir / "runs").glob("*.csv") if parse_csv_name(p.name))
    if not files:
        raise ValueError(f"{run_dir}: no runs/<strategy>_seed<k>.csv (a `katana-curiosity "
                         "paper` output folder?)")
    runs = [read_run_csv(p) for p in files]
    runs.sort(key=lambda r: (r.strategy, r.seed))
    return summary, runs


# -- per-seed values -----------------------------------------------------------------------


def final_overall(run: AbstractRun) -> float:
    return float(run.kl_overall[-1])


def final_at(height: int):
    def value(run: AbstractRun) -> float:
        return float(run.kl[height][-1]) if height in run.kl else math.nan
    return value


def low_heights(run: AbstractRun) -> list[int]:
    """The two lowest learned heights (1 and 2 in the paper's world)."""
    return run.heights[:2]


def early_low_kl(run: AbstractRun) -> float:
    """Mean KL of the two lowest heights after EARLY experiments."""
    return float(np.mean([run.at(run.kl[h], EARLY) for h in low_heights(run)]))


def low_improvement_after_early(run: AbstractRun) -> float:
    """Mean KL of the two lowest heights after EARLY experiments minus at the end."""
    return early_low_kl(run) - float(np.mean([run.kl[h][-1] for h in low_heights(run)]))


def early_share_of_decrease(run: AbstractRun) -> float:
    """Mean over the two lowest heights of (KL at 0 - KL after EARLY) / (KL at 0 - final KL);
    NaN where a height's KL did not fall overall."""
    shares = []
    for h in low_heights(run):
        kl = run.kl[h]
        total = kl[0] - kl[-1]
        shares.append((kl[0] - run.at(kl, EARLY)) / total if total > 0 else math.nan)
    return float(np.mean(shares))


def half_life(kl: np.ndarray, experiment: np.ndarray) -> float:
    """Experiments until the KL first comes halfway down from its start to its final value."""
    target = kl[-1] + 0.5 * (kl[0] - kl[-1])
    return float(experiment[int(np.argmax(kl <= target))])


def rank_correlation(x: Sequence[float], y: Sequence[float]) -> float:
    """Spearman's rho (scipy.stats.spearmanr); NaN with fewer than two points or a constant
    side."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    if len(x) < 2 or np.ptp(x) == 0 or np.ptp(y) == 0:
        return math.nan
    return float(sps.spearmanr(x, y).statistic)


def half_life_order(run: AbstractRun) -> float:
    """Spearman's rho between height and its KL half-life: > 0 when lower heights learn
    faster."""
    hs = run.heights
    return rank_correlation(hs, [half_life(run.kl[h], run.experiment) for h in hs])


def direct_heights(run: AbstractRun) -> list[int]:
    """The learned heights with direct experience."""
    return [h for h in run.heights if h in run.direct and run.direct[h][-1] > 0]


def stage_order(run: AbstractRun) -> float:
    """Spearman's rho between height and the experiment by which half of its direct
    experience was made: > 0 when heights are explored in order."""
    hs = direct_heights(run)
    mid = [float(run.experiment[int(np.argmax(run.direct[h] >= run.direct[h][-1] / 2))])
           for h in hs]
    return rank_correlation(hs, mid)


def stage_overlap(run: AbstractRun) -> float:
    """Share of consecutive heights (h, h+1) with direct experience where direct exploration
    of h+1 begins before that of h has ended (its last direct query); NaN with fewer than two
    such heights."""
    hs = direct_heights(run)
    pairs = [(h, h + 1) for h in hs if h + 1 in hs]
    if not pairs:
        return math.nan

    def first(h):  # the first row with direct experience at h
        return run.experiment[int(np.argmax(run.direct[h] > 0))]

    def last(h):  # the first row by which all of h's direct experience was made
        return run.experiment[int(np.argmax(run.direct[h] >= run.direct[h][-1]))]

    return float(np.mean([first(b) < last(a) for a, b in pairs]))


def planned_below_direct(run: AbstractRun) -> float:
    """Mean height of the direct placements minus that of the planned ones, at the end: > 0
    when planning builds on the lower heights to reach the higher ones."""
    def mean_height(counts: dict[int, np.ndarray]) -> float:
        n = {h: c[-1] for h, c in counts.items()}
        total = sum(n.values())
        return sum(h * v for h, v in n.items()) / total if total else math.nan

    return mean_height(run.direct) - mean_height(run.planned)


def min_final_kl(run: AbstractRun) -> float:
    """The lowest final KL over the learned heights."""
    return float(min(run.kl[h][-1] for h in run.heights))


# -- the claims ----------------------------------------------------------------------------

S32 = "section 3.2"
OVERALL = "final overall KL (the mean over the learned heights after the last experiment)"
Q1_BEST = "The overall performance of Q1 is the best, closely followed by Q10"
CONF_WORDS = ("The confidence-based method performs much better than random method, but is "
              "still inferior compared to query-based methods Q1 and Q10")
RANDOM_LEAST = ("This undirected exploration behavior makes random exploration the least "
                "efficient method compared to the other three (informed) exploration methods")
RANDOM_BEST_LOW = ("The random method ... keeps improving its learned models and achieves the "
                   "best models for height one and two, among the four methods")
RANDOM_WORST_HIGH = ("However, for the other five higher heights, its learned models are much "
                     "worse compared to the rest")


NAMES = {"q1": "Q1", "q10": "Q10", "conf": "Conf", "random": "Random"}
#: Random and the three informed methods, in the order the statistics take them
RANDOM_FIRST = ("random", "q1", "q10", "conf")
FIG9, FIG5, FIG4 = (f"{S32}, Figure {n}" for n in (9, 5, 4))
GREATER = stats.Claimed("greater")


class Measure(NamedTuple):
    """A claim of section 3.2 and how the run CSVs measure it: `value` of each run of the
    strategies, per seed, in the order `statistic` takes them."""

    spec: ClaimSpec
    strategies: tuple[str, ...]
    value: Callable[[AbstractRun], float]
    statistic: stats.Statistic
    note: str = ""


def _values(runs: Sequence[AbstractRun], strategy: str, value) -> dict[int, float]:
    return {r.seed: value(r) for r in runs if r.strategy == strategy}


def _overall_pair(cid: str, words: str, worse: str, better: str) -> Measure:
    """Figure 9: `better` ends with a lower overall KL than `worse`."""
    return Measure(ClaimSpec(cid, FIG9, words,
                             f"{NAMES[worse]}'s {OVERALL} minus {NAMES[better]}'s", GREATER,
                             "nats"), (worse, better), final_overall, stats.difference)


def _seed_mean(strategy: str, spec: ClaimSpec, value, note: str = "") -> Measure:
    """A claim on one strategy's runs: the mean over its seeds of `value`."""
    return Measure(spec, (strategy,), value, stats.mean, note)


def figure_9_overall() -> list[Measure]:
    """Figure 9, the final overall KL: Q1 best, closely followed by Q10, then Conf, Random
    last."""
    close = stats.Claimed("within", bounds=(-CLOSE_MARGIN, CLOSE_MARGIN))
    return [
        _overall_pair("q1-better-than-q10", Q1_BEST, "q10", "q1"),
        _overall_pair("q1-better-than-conf", Q1_BEST, "conf", "q1"),
        _overall_pair("q1-better-than-random", Q1_BEST, "random", "q1"),
        Measure(ClaimSpec("q10-close-to-q1", FIG9, Q1_BEST,
                          f"(Q10's {OVERALL} - Q1's) / Q1's; closely taken as within "
                          f"+-{CLOSE_MARGIN:.0%}", close),
                ("q10", "q1"), final_overall, stats.relative_difference),
        _overall_pair("conf-better-than-random", CONF_WORDS, "random", "conf"),
        _overall_pair("conf-worse-than-q10", CONF_WORDS, "conf", "q10"),
        Measure(ClaimSpec("random-least-efficient", FIG9, RANDOM_LEAST,
                          f"Random's {OVERALL} minus the highest of Q1's, Q10's and Conf's",
                          GREATER, "nats"),
                RANDOM_FIRST, final_overall, stats.first_minus_others_max),
    ]


def figure_9_heights(heights: Sequence[int]) -> list[Measure]:
    """Figure 9 per height: Random's final KL the lowest at the two lowest heights, the
    highest at every other."""
    best = [Measure(ClaimSpec(f"random-best-at-height-{h}", FIG9, RANDOM_BEST_LOW,
                              f"the lowest of Q1's, Q10's and Conf's final KL at height {h} "
                              "minus Random's", GREATER, "nats"),
                    RANDOM_FIRST, final_at(h), stats.others_min_minus_first)
            for h in heights[:2]]
    return best + [Measure(ClaimSpec(f"random-worst-at-height-{h}", FIG9, RANDOM_WORST_HIGH,
                                     f"Random's final KL at height {h} minus the highest of "
                                     "Q1's, Q10's and Conf's", GREATER, "nats"),
                           RANDOM_FIRST, final_at(h), stats.first_minus_others_max)
                   for h in heights[2:]]


def figure_9_early() -> list[Measure]:
    """Figure 9's first EARLY experiments: Random slower but still improving after them, Q1
    close by then and saturated."""
    return [
        Measure(ClaimSpec("random-slower-early", FIG9,
                          "The random method, on the other hand, though making much slower "
                          "progress than Q1 and Q10 in the first 1000 timesteps",
                          f"Random's KL after {EARLY} experiments (mean of heights 1 and 2) "
                          "minus the higher of Q1's and Q10's", GREATER, "nats"),
                ("random", "q1", "q10"), early_low_kl, stats.first_minus_others_max),
        _seed_mean("random", ClaimSpec(
            "random-keeps-improving", FIG9,
            "The random method ... keeps improving its learned models",
            f"Random's KL after {EARLY} experiments minus its final KL (mean of heights 1 "
            "and 2)", GREATER, "nats"), low_improvement_after_early),
        _seed_mean("q1", ClaimSpec(
            "q1-close-then-saturates", FIG9,
            "we see that Q1 gets close to the true model exponentially fast in the first 1000 "
            "timesteps, then saturates",
            f"the share of Q1's whole KL decrease (step 0 to the last) made by step {EARLY}, "
            f"mean of heights 1 and 2; saturated taken as more than {SATURATED_SHARE:.0%}",
            stats.Claimed("greater", SATURATED_SHARE)), early_share_of_decrease),
    ]


def figure_5() -> list[Measure]:
    """Figure 5, Q1's KL per height: faster down at lower heights, saturating above zero."""
    return [
        _seed_mean("q1", ClaimSpec(
            "q1-faster-at-lower-heights", FIG5,
            "These distances tend to diminish exponentially with experience, and they "
            "diminish faster at lower heights, where experience is easier to get",
            "Spearman's rho, per Q1 seed, between height and the experiments its KL takes to "
            "come halfway down from its start to its final value", GREATER), half_life_order),
        _seed_mean("q1", ClaimSpec(
            "q1-saturates-above-zero", FIG5,
            "The saturation levels are non-zero due to the noise level in the training "
            "labels, the query condition scaling factor alpha, and the confidence-interval "
            "threshold theta",
            "the lowest final KL over the heights, per Q1 seed", GREATER, "nats"),
            min_final_kl),
    ]


def figure_4(row_step: int) -> list[Measure]:
    """Figure 4, Q1's developmental stages: in order of height, planning on the lower
    heights, overlapping (`row_step`: the experiments between two CSV rows)."""
    return [
        _seed_mean("q1", ClaimSpec(
            "q1-stages-in-order", FIG4,
            "These plots show the developmental stages of the learning agent, where easier "
            "problems, such as direct exploration at height one, are learned first, and more "
            "difficult problems are learned later",
            "Spearman's rho, per Q1 seed, between height and the experiment by which half of "
            "that height's direct experience was made", GREATER), stage_order),
        _seed_mean("q1", ClaimSpec(
            "q1-plans-on-lower-heights", FIG4,
            "the acquired knowledge at lower heights is exploited for planning, and this "
            "planning helps the agent get to the higher heights",
            "mean height of Q1's direct placements minus that of its planned placements, per "
            "seed", GREATER, "heights"), planned_below_direct),
        _seed_mean("q1", ClaimSpec(
            "q1-stages-overlap", FIG4,
            "the exploration at higher heights does, in fact, start before the direct "
            "exploration of lower heights terminates",
            "the share of consecutive heights (h, h+1) whose first direct query at h+1 comes "
            "before the last at h, per Q1 seed (claimed: for most pairs)",
            stats.Claimed("greater", 0.5)), stage_overlap,
            note=f"CSV rows every {row_step} experiments: times are known to a row"),
    ]


def not_evaluated_32(have: set[str]) -> list[dict]:
    """The claims of section 3.2 the run folder cannot decide (`have`: its strategies)."""
    out = [{
        "id": "focus-on-hard-features", "where": f"{S32}, Figures 6-8",
        "paper": "Our system first explores much of the input space, then quickly shifts its "
                 "attention to this \"hard-to-learn\" input region, where most of its "
                 "exploration effort is spent",
        "why": "the run folder keeps experience per height, not per feature; fig6-8.png draw "
               "it for the first seed"}]
    missing = [s for s in PAPER_STRATEGIES if s not in have]
    if missing:
        out.append({
            "id": "strategies-missing", "where": FIG9,
            "paper": "we compare its performance to three other methods",
            "why": f"no runs of {', '.join(missing)} in the folder: the claims naming them "
                   "are INCONCLUSIVE (not measured)"})
    return out


def section_32(runs: Sequence[AbstractRun], settings: Settings = DEFAULT_SETTINGS
               ) -> tuple[list[dict], list[dict]]:
    """Every claim of section 3.2 the run CSVs decide, and the ones they cannot."""
    heights = sorted({h for r in runs for h in r.heights})
    measures = [*figure_9_overall(), *figure_9_heights(heights), *figure_9_early(),
                *figure_5(), *figure_4(_row_step(runs))]
    claims = [evaluate(m.spec, {s: _values(runs, s, m.value) for s in m.strategies},
                       m.statistic, settings, m.note) for m in measures]
    return claims, not_evaluated_32({r.strategy for r in runs})


def _row_step(runs: Sequence[AbstractRun]) -> int:
    steps = [int(np.min(np.diff(r.experiment))) for r in runs if len(r.experiment) > 1]
    return min(steps) if steps else 0


def claims_document(run_dir: Path, settings: Settings = DEFAULT_SETTINGS,
                    command: str = "") -> dict:
    """claims.json of a `katana-curiosity paper` run folder."""
    summary, runs = load_folder(run_dir)
    claims, not_evaluated = section_32(runs, settings)
    seeds = {s: sorted(r.seed for r in runs if r.strategy == s)
             for s in dict.fromkeys(r.strategy for r in runs)}
    context = {"experiments": (summary or {}).get("experiments",
                                                 int(max(r.experiment[-1] for r in runs))),
               "seeds": seeds, "parameters": (summary or {}).get("parameters")}
    return document("3.2", str(run_dir), command or f"katana-curiosity claims {run_dir}",
                    claims, not_evaluated, settings, **context)
