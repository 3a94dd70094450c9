"""A claim, evaluated: its words in the paper, what is measured for it, the per-seed values,
the statistic with its bootstrap interval, the verdict, and the document (claims.json and
claims.md) that holds every claim of a run folder."""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import stats
from .report import CLAIMS_JSON, CLAIMS_MD, render_markdown, render_terminal

#: the layout of claims.json (bumped when a field changes meaning)
FORMAT = 1


@dataclass(frozen=True)
class ClaimSpec:
    """One claim: an id, where the paper makes it and its words, and the operational
    definition of what is measured (the statistic, and what the claim says of it)."""

    id: str
    where: str  # "section 3.2, Figure 9"
    paper: str  # the paper's words
    measured_as: str  # the statistic over the per-seed values, in words
    claimed: stats.Claimed
    unit: str = ""


@dataclass(frozen=True)
class RunNaming:
    """How a run folder names each run's file or folder after its strategy and seed:
    `template` (str.format with strategy and seed) and the pattern that reads a name back
    (groups strategy and seed)."""

    template: str
    pattern: re.Pattern

    def name(self, strategy: str, seed: int) -> str:
        return self.template.format(strategy=strategy, seed=seed)

    def parse(self, name: str) -> tuple[str, int] | None:
        """(strategy, seed) of a run's name, or None for any other name."""
        m = self.pattern.fullmatch(name)
        return (m["strategy"], int(m["seed"])) if m else None


@dataclass(frozen=True)
class Settings:
    """How intervals are made: resamples, the resampling seed, the level, and the power of the
    seeds-to-decide estimate."""

    resamples: int = stats.RESAMPLES
    seed: int = stats.SEED
    level: float = stats.LEVEL
    power: float = stats.POWER
    min_seeds: int = stats.MIN_SEEDS

    def to_json(self) -> dict:
        return {
            "interval": f"{self.level:.0%} percentile bootstrap over seeds, each strategy's "
            "seeds resampled on their own (stratified, as rliable), scipy.stats.bootstrap",
            "resamples": self.resamples, "seed": self.seed, "level": self.level,
            "min_seeds": self.min_seeds,
            "verdict": "PASS: the interval excludes the null on the claimed side (or lies "
            "within the claimed bounds); FAIL: it excludes it on the other side (or lies "
            "wholly outside the bounds); INCONCLUSIVE otherwise",
            "seeds_to_decide": f"normal approximation from the observed effect and the "
            f"bootstrap standard error, {self.power:.0%} power, per strategy",
            "rank_test": "one-sided Mann-Whitney U (scipy.stats.mannwhitneyu); probability of "
            "improvement = U / (n1 n2)",
            "paired": "supplementary: the same interval with one seed's values in every "
            "strategy resampled together (a seed fixes the abstract world's true models); "
            "not used for the verdict",
        }


DEFAULT_SETTINGS = Settings()


def _number(x: float | None, digits: int = 6) -> float | None:
    """A JSON-safe float rounded to `digits` significant digits (None if not finite)."""
    if x is None or not math.isfinite(x):
        return None
    return float(f"{x:.{digits}g}")


def evaluate(spec: ClaimSpec, groups: Mapping[str, Mapping[int, float]],
             statistic: stats.Statistic, settings: Settings = DEFAULT_SETTINGS,
             note: str = "") -> dict:
    """The claim's entry of claims.json: `statistic` over the groups' per-seed values
    ({strategy: {seed: value}}, in the statistic's argument order; NaN values, seeds where the
    quantity is undefined, are left out), its interval, verdict and seeds, for a two-group
    difference the rank test, for groups of the same seeds the interval paired by seed, and
    for an undecided claim the seeds that would decide it."""
    kept = {k: {int(s): float(v) for s, v in sorted(vs.items())
                if v is not None and math.isfinite(v)} for k, vs in groups.items()}
    values = {k: np.array(list(vs.values()), dtype=float) for k, vs in kept.items()}
    seeds = {k: len(v) for k, v in values.items()}
    entry = {
        "id": spec.id, "where": spec.where, "paper": spec.paper,
        "measured_as": spec.measured_as, "claimed": spec.claimed.text(), "unit": spec.unit,
        "verdict": stats.INCONCLUSIVE, "effect": None, "ci95": None, "seeds": seeds,
        "seeds_to_decide": None, "prob_improvement": None, "p_value": None,
        "paired": None,
        "values": {k: {str(s): _number(v) for s, v in vs.items()} for k, vs in kept.items()},
        "note": note,
    }
    if not seeds or min(seeds.values()) == 0:
        missing = [k for k, n in seeds.items() if n == 0]
        entry["note"] = _join(note, f"not measured: no seed of {', '.join(missing)}")
        return entry
    if min(seeds.values()) < settings.min_seeds:
        entry["effect"] = _number(float(statistic(*values.values(), axis=-1)))
        entry["note"] = _join(note, f"fewer than {settings.min_seeds} seeds in a group: no "
                              "interval and no verdict")
        return entry
    est = stats.bootstrap_estimate(list(values.values()), statistic, settings.resamples,
                                   settings.seed, settings.level)
    entry["effect"] = _number(est.effect)
    entry["ci95"] = [_number(est.ci[0]), _number(est.ci[1])]
    entry["verdict"] = stats.verdict(est.ci, spec.claimed)
    if entry["verdict"] == stats.INCONCLUSIVE:
        entry["seeds_to_decide"] = stats.seeds_to_decide(est, spec.claimed, settings.power,
                                                         settings.level)
    if statistic is stats.difference:
        a, b = values.values()
        prob, p = stats.rank_test(a, b, spec.claimed)
        entry["prob_improvement"], entry["p_value"] = _number(prob, 4), _number(p, 4)
    entry["paired"] = _paired(spec, list(kept.values()), statistic, settings)
    return entry


def _paired(spec: ClaimSpec, groups: Sequence[Mapping[int, float]], statistic: stats.Statistic,
            settings: Settings) -> dict | None:
    """The statistic's interval with the seeds paired (one seed's values in every group
    resampled together), supplementary to the stratified interval the verdict uses: where a
    seed fixes the world (the abstract world's true models), pairing takes the worlds' spread
    out of a comparison. None unless there are two or more groups holding the same two or more
    seeds."""
    seeds = sorted(groups[0]) if groups else []
    if len(groups) < 2 or len(seeds) < 2 or any(sorted(g) != seeds for g in groups):
        return None
    arrays = [np.array([g[s] for s in seeds]) for g in groups]
    res = stats.bootstrap_result(arrays, statistic, settings.resamples, settings.seed,
                                 settings.level, paired=True)
    ci = (float(res.confidence_interval.low), float(res.confidence_interval.high))
    return {"ci95": [_number(ci[0]), _number(ci[1])], "seeds": len(seeds),
            "verdict": stats.verdict(ci, spec.claimed)}


def _join(*parts: str) -> str:
    return "; ".join(p for p in parts if p)


def document(section: str, source: str, command: str, claims: Sequence[dict],
             not_evaluated: Sequence[dict], settings: Settings, **context) -> dict:
    """claims.json: the run folder, the command, how intervals were made, every claim, and the
    claims that could not be evaluated from the folder (each with why)."""
    counts = {v: sum(c["verdict"] == v for c in claims) for v in stats.VERDICTS}
    return {"format": FORMAT, "section": section, "source": source, "command": command,
            "method": settings.to_json(), **context, "counts": counts,
            "claims": list(claims), "not_evaluated": list(not_evaluated)}


def write(out: Path, doc: dict) -> tuple[Path, Path]:
    """claims.json and claims.md in `out` (beside summary.json)."""
    out = Path(out)
    json_path, md_path = out / CLAIMS_JSON, out / CLAIMS_MD
    json_path.write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    md_path.write_text(render_markdown(doc, heading=True) + "\n", encoding="utf-8")
    return json_path, md_path


def finish(out: Path, doc: dict, prog: str) -> int:
    """Write the document, print the report and where it went; 0."""
    json_path, md_path = write(out, doc)
    print(render_terminal(doc))
    print(f"{prog}: wrote {json_path} and {md_path}")
    return 0
