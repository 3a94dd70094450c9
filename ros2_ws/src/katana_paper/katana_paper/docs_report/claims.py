"""The paper's claims of sections 3.2 and 3.3 on the pages. The verdicts are not made here:
`katana-curiosity claims` and `katana-robot claims` judge every claim from the run folders
with bootstrap intervals over the seeds and write claims.json (committed under docs/results/
beside the summaries); this module renders those files with katana_paper.claims.report, the
renderer of claims.md, so that the pages and the reports are one source. Also the small
helpers of the KL tables."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

from ..claims.report import counts_text, render_markdown
from .formatting import Json, finite, get, num
from .provenance import not_measured

PAPER_ORDER = ("q1", "q10", "conf", "random")


def heights_of(strategies: Mapping) -> list[str]:
    """Every height with a final KL in any strategy, ascending: the columns of the KL tables."""
    return sorted({h for s in strategies.values() for h in (s.get("final_kl") or {})}, key=int)


def ranking(strategies: Mapping) -> list[str]:
    """Strategies by final overall KL, best first."""
    scored = [(s["final_kl_overall"], k) for k, s in strategies.items()
              if finite(s.get("final_kl_overall"))]
    return [k for _, k in sorted(scored)]


def pct(part: Json, whole: Json, digits: int = 0) -> str:
    """part / whole in per cent, '0' where it cannot be computed (nothing to divide by)."""
    return num(100 * part / whole, digits) if finite(part) and finite(whole) and whole else "0"


def uncertain_pairs(
    truth: Json, low: float = 0.05, high: float = 0.95
) -> list[tuple[int, int, float]]:
    """(height, action, P) of the measured pairs whose outcome is far from certain."""
    return sorted((int(h), int(a), v)
                  for h, row in (get(truth, "p_stable", default={}) or {}).items()
                  for a, v in row.items() if finite(v) and low < v < high)


def claims_mismatch(claims: Json, summary: Json) -> str:
    """A sentence when claims.json was judged from other runs than the summary shows (other
    experiments per run, or other seeds); '' when they agree or either is missing."""
    if claims is None or summary is None:
        return ""
    seeds = {int(s) for ss in (get(claims, "seeds", default={}) or {}).values() for s in ss}
    theirs = {int(s) for s in get(summary, "seeds", default=[]) or []}
    runs = get(claims, "experiments"), get(summary, "experiments")
    if (seeds and theirs and seeds != theirs) or (None not in runs and runs[0] != runs[1]):
        return ("*The claims were judged from other runs than the table above shows* (seeds "
                f"{sorted(seeds)}, {runs[0]} experiments); judge the runs of the summary again "
                "and collect both.")
    return ""


def claims_section(claims: Json, summary: Json, name: str) -> str:
    """The claims of a claims.json as Markdown (how they were judged, the counts, one item
    per claim), or what stands in for the file when it is missing."""
    if claims is None:
        return not_measured(name)
    mismatch = claims_mismatch(claims, summary)
    return render_markdown(claims) + (f"\n\n{mismatch}" if mismatch else "")


@dataclass(frozen=True)
class RunSection:
    """A run's section of REPRODUCING.md, called with the run's summary and its claims.json:
    the run's settings, what its table shows and the table, then the verdicts on the paper's
    claims (results `<name>-claims`); what stands in for the run when the summary (results
    `name`) is missing."""

    name: str
    settings: Callable[[Json], str]
    table_about: str
    table: Callable[[Json], str]
    claims_about: str

    def __call__(self, data: Json, claims: Json = None) -> str:
        if data is None:
            return not_measured(self.name)
        return "\n".join([self.settings(data), "", self.table_about, "", self.table(data), "",
                          self.claims_about, "",
                          claims_section(claims, data, f"{self.name}-claims")])


def claims_counts(claims: Json) -> str:
    """'15 PASS, 1 FAIL, 6 INCONCLUSIVE of 22 claims', for the README's row."""
    return counts_text(claims if isinstance(claims, Mapping) else {})
