"""How figures are written on the pages, in one place so that every page writes a missing
value, a ratio or a target the same way, and a result file with a level missing reads as
"not recorded" instead of failing."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

# A value read from a result file (a dict, list, number, string or None): the pages read files
# whose levels may be missing or of another kind, so each helper takes any of them.
Json = Any

NOT_RECORDED = "not recorded"
NONE_MEASURED = "none measured"


def finite(x: Json) -> bool:
    """A real, finite number: what a figure must be before it is printed or divided (not a bool)."""
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def num(x: Json, digits: int = 3) -> str:
    """A float with `digits` decimals; ints and values of 1000 or more as whole numbers with
    thousands separators; anything else 'not recorded'."""
    if not finite(x):
        return NOT_RECORDED
    if isinstance(x, int) or abs(x) >= 1000:
        return f"{round(x):,}"
    return f"{x:.{digits}f}"


def ratio(measured: Json, floor: Json, digits: int = 2) -> str:
    """measured / floor as '1.23x', or '-' when either is missing."""
    if not (finite(measured) and finite(floor)) or floor == 0:
        return "-"
    return f"{measured / floor:.{digits}f}x"


def get(data: Json, *keys: str, default: Json = None) -> Json:
    """data[k1][k2]... or `default` where any level is missing."""
    for key in keys:
        if not isinstance(data, Mapping) or key not in data:
            return default
        data = data[key]
    return data


def strategies_of(data: Json) -> dict:
    """Per-strategy results of a summary (older files call them methods)."""
    return get(data, "strategies") or get(data, "methods") or {}


def experiments_of(data: Json) -> Json:
    """Experiments per run of an abstract-world summary (older files call them steps)."""
    return get(data, "experiments", default=get(data, "steps"))


def table(header: Sequence[str], rows: Sequence[Sequence]) -> str:
    """A Markdown table, every cell as str() gives it, so that the pages need no table code."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def met_text(value: Json, target: Json, at_most: bool = True) -> str:
    """'10 (met)' or '10 (not met)' against a target; '-' without one."""
    if not finite(target):
        return "-"
    if not finite(value):
        return f"{target:,g}"
    ok = value <= target if at_most else value >= target
    return f"{target:,g} ({'met' if ok else 'not met'})"


def count_of(share: Json, trials: Json) -> str:
    """'7 / 10' from a share of successes and the number of trials."""
    if not (finite(share) and finite(trials)):
        return NOT_RECORDED
    return f"{round(share * trials)} / {trials}"


_DISPLAY = {"q1": "Q1", "q10": "Q10", "conf": "Conf", "random": "Random", "lp": "LP",
            "variance": "Variance", "rmax": "R-max", "egreedy": "eps-greedy"}


def display(strategy: str) -> str:
    """The strategy's name as the paper writes it (Q1, Conf, ...); an unknown one as it is."""
    return _DISPLAY.get(strategy, strategy)
