"""claims.json rendered as text: claims.md (and the claim sections of docs/REPRODUCING.md and
README.md, which render the committed claims.json with the same functions) and the terminal
table. Pure functions of the parsed document; no statistics are computed here."""

from __future__ import annotations

import math
from collections.abc import Mapping

CLAIMS_JSON = "claims.json"
CLAIMS_MD = "claims.md"
VERDICT_ORDER = ("PASS", "FAIL", "INCONCLUSIVE")


def fmt(x) -> str:
    """A number with three significant digits; '-' for none."""
    if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
        return "-"
    return f"{x:.3g}"


def seeds_text(seeds: Mapping) -> str:
    """'seeds: q1 10, random 10' (or '10 seeds of q1' for one group)."""
    if len(seeds) == 1:
        (k, n), = seeds.items()
        return f"{n} seed{'s' * (n != 1)} of {k}"
    return "seeds: " + ", ".join(f"{k} {n}" for k, n in seeds.items())


def effect_text(claim: Mapping, unit: bool = False) -> str:
    """'0.0478 (95 % CI 0.0391 to 0.0571)' (with `unit`: '0.0478 nats (...)'), or why there
    is none."""
    ci = claim.get("ci95")
    if claim.get("effect") is None:
        return "no value"
    value = fmt(claim["effect"]) + (f" {claim['unit']}" if unit and claim.get("unit") else "")
    if not ci:
        return f"{value} (no interval)"
    return f"{value} (95 % CI {fmt(ci[0])} to {fmt(ci[1])})"


def counts_text(doc: Mapping) -> str:
    """'14 PASS, 4 FAIL, 3 INCONCLUSIVE of 21 claims'."""
    counts = doc.get("counts") or {}
    n = len(doc.get("claims") or [])
    return ", ".join(f"{counts.get(v, 0)} {v}" for v in VERDICT_ORDER) + f" of {n} claims"


def decide_text(claim: Mapping) -> str:
    """For an undecided claim: how many seeds would decide it, said to be an estimate."""
    if claim.get("verdict") != "INCONCLUSIVE":
        return ""
    n = claim.get("seeds_to_decide")
    if n is None:
        return ""
    return (f" About {n} seeds per strategy would decide it (a normal approximation from the "
            "observed effect and its bootstrap spread, 80 % power).")


def paired_text(claim: Mapping) -> str:
    """Where the interval paired by seed gives another verdict, that verdict and interval
    (a supplement: the verdict is the stratified interval's)."""
    paired = claim.get("paired") or {}
    if not paired or paired.get("verdict") == claim.get("verdict"):
        return ""
    ci = paired.get("ci95") or [None, None]
    return (f" (paired by seed: {paired.get('verdict')}, 95 % CI {fmt(ci[0])} to "
            f"{fmt(ci[1])})")


def claim_item(i: int, claim: Mapping) -> str:
    """One numbered Markdown item: verdict, the paper's words, the measure and the numbers."""
    rank = ""
    if claim.get("prob_improvement") is not None:
        rank = (f"; probability of improvement {fmt(claim['prob_improvement'])}, one-sided "
                f"Mann-Whitney p = {fmt(claim.get('p_value'))}")
    note = f" ({claim['note'][:1].upper()}{claim['note'][1:]}.)" if claim.get("note") else ""
    return (f"{i}. **{claim.get('verdict')}**{paired_text(claim)} \"{claim.get('paper')}\" "
            f"({claim.get('where')}). "
            f"*Measured:* {claim.get('measured_as')}, claimed {claim.get('claimed')}: "
            f"{effect_text(claim, unit=True)}, "
            f"{seeds_text(claim.get('seeds') or {})}{rank}.{note}{decide_text(claim)}")


def method_text(doc: Mapping) -> str:
    """The sentence that says how the verdicts were made and by which command."""
    m = doc.get("method") or {}
    resamples = m.get("resamples")
    return (f"Judged by `{doc.get('command')}` from the run folder `{doc.get('source')}`: a "
            f"{fmt(100 * m.get('level', 0.95))} % percentile bootstrap over the seeds, each "
            f"strategy's seeds resampled on their own"
            + (f" ({resamples:,} resamples)" if isinstance(resamples, int) else "")
            + ". PASS when the interval excludes the null on the claimed side (or lies within "
            "the claimed bounds), FAIL when it excludes it on the other side (or lies wholly "
            "outside the bounds), INCONCLUSIVE otherwise"
            + (f", and always with fewer than {m['min_seeds']} seeds in a strategy"
               if isinstance(m.get("min_seeds"), int) else "")
            + ". Where the interval with the seeds "
            "paired (one seed's runs resampled together) gives another verdict, it stands "
            "beside the verdict.")


def render_markdown(doc: Mapping, heading: bool = False) -> str:
    """The claims as Markdown: how they were judged, the counts, one item per claim, and the
    claims the run folder cannot decide at all."""
    lines = []
    if heading:
        lines += [f"# The paper's claims, section {doc.get('section')}", ""]
    lines += [method_text(doc) + f" **{counts_text(doc)}.**", ""]
    lines += [claim_item(i, c) for i, c in enumerate(doc.get("claims") or [], 1)]
    skipped = doc.get("not_evaluated") or []
    if skipped:
        lines += ["", "Not evaluated from the run folder:", ""]
        lines += [f"- \"{s.get('paper')}\" ({s.get('where')}): {s.get('why')}." for s in skipped]
    return "\n".join(lines)


def render_terminal(doc: Mapping) -> str:
    """A table for the terminal: verdict, claim id, effect with its interval, seeds, and for an
    undecided claim the seeds that would decide it."""
    rows = [("verdict", "claim", "effect (95 % CI)", "seeds", "seeds to decide")]
    for c in doc.get("claims") or []:
        rows.append((c.get("verdict", ""), c.get("id", ""), effect_text(c).replace(
            "95 % CI ", ""), seeds_text(c.get("seeds") or {}).removeprefix("seeds: "),
            str(c["seeds_to_decide"]) if c.get("seeds_to_decide") is not None else ""))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = [f"section {doc.get('section')} claims, {doc.get('source')}: {counts_text(doc)}"]
    lines += ["  ".join(cell.ljust(w) for cell, w in zip(r, widths, strict=True)).rstrip()
              for r in rows]
    for s in doc.get("not_evaluated") or []:
        lines.append(f"not evaluated: {s.get('id', s.get('where'))}: {s.get('why')}")
    return "\n".join(lines)
