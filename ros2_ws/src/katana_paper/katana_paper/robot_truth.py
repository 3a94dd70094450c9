"""The measured ground truth of the robot's world, and how far a learned model is from it.

On the robot there is no `u^s` to draw (section 3.1 has one per height): the truth is what
placements in the simulator actually do. `katana-robot truth` measures, for every (height,
action) the fovea can realise, the fraction of placements that stayed, with a Wilson 95 %
interval; pairs that cannot occur (on the table only action 1, "no overlap") are kept apart as
impossible, never as zeros, and count in no divergence. Which outcome a placement had is read
from the simulator's ground truth (`placement_stayed`), in the order of `truth_schedule`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .metrics import MARGIN_EPS, bernoulli_kl, stability_probability

#: z of a two-sided 95 % interval
Z95 = 1.959963984540054


def wilson_interval(stayed: int, trials: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (Wilson 1927); (0, 1) with no trials."""
    if trials < 0 or not 0 <= stayed <= trials:
        raise ValueError(f"need 0 <= stayed <= trials, got {stayed} of {trials}")
    if trials == 0:
        return 0.0, 1.0
    p = stayed / trials
    z2 = z * z
    centre = (p + z2 / (2 * trials)) / (1 + z2 / trials)
    half = z / (1 + z2 / trials) * math.sqrt(p * (1 - p) / trials + z2 / (4 * trials * trials))
    # at k = 0 and k = n the exact ends are 0 and 1; rounding must not move them inside
    lo = 0.0 if stayed == 0 else max(0.0, centre - half)
    hi = 1.0 if stayed == trials else min(1.0, centre + half)
    return lo, hi


@dataclass
class TruthTable:
    """Counts of stayed / tried placements per (height, action); actions are 1-based."""

    n_states: int
    n_actions: int
    stayed: np.ndarray = field(init=False)
    trials: np.ndarray = field(init=False)
    possible: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        shape = (self.n_states, self.n_actions)
        self.stayed = np.zeros(shape, dtype=int)
        self.trials = np.zeros(shape, dtype=int)
        self.possible = np.ones(shape, dtype=bool)

    def mark_impossible(self, state: int, action: int) -> None:
        self.possible[state, action - 1] = False

    def record(self, state: int, action: int, label: int) -> None:
        if label not in (-1, 1):
            raise ValueError(f"label must be +1 or -1, got {label!r}")
        if not self.possible[state, action - 1]:
            raise ValueError(f"(height {state}, action {action}) cannot occur")
        self.trials[state, action - 1] += 1
        self.stayed[state, action - 1] += label == 1

    def p_stable(self) -> np.ndarray:
        """Measured P(stable) per pair; NaN where impossible or never tried."""
        with np.errstate(invalid="ignore", divide="ignore"):
            p = self.stayed / self.trials
        return np.where(self.possible & (self.trials > 0), p, np.nan)

    def to_json(self) -> dict:
        """The truth.json layout: p_stable, trials and interval95 keyed by height and action,
        with impossible pairs listed under `impossible` and absent from the tables."""
        p = self.p_stable()
        out: dict = {"p_stable": {}, "trials": {}, "stayed": {}, "interval95": {}, "impossible": []}
        for s in range(self.n_states):
            for key in ("p_stable", "trials", "stayed", "interval95"):
                out[key][str(s)] = {}
            for a in range(self.n_actions):
                if not self.possible[s, a]:
                    out["impossible"].append([s, a + 1])
                    continue
                n, k = int(self.trials[s, a]), int(self.stayed[s, a])
                out["trials"][str(s)][str(a + 1)] = n
                out["stayed"][str(s)][str(a + 1)] = k
                out["p_stable"][str(s)][str(a + 1)] = None if n == 0 else float(p[s, a])
                out["interval95"][str(s)][str(a + 1)] = list(wilson_interval(k, n))
        return out

    @classmethod
    def from_json(cls, data: Mapping) -> TruthTable:
        states = sorted(int(s) for s in data["trials"])
        actions = max(
            [int(a) for row in data["trials"].values() for a in row]
            + [pair[1] for pair in data.get("impossible", [])]
        )
        table = cls(max(states) + 1, actions)
        for s, a in data.get("impossible", []):
            table.mark_impossible(int(s), int(a))
        for s, row in data["trials"].items():
            for a, n in row.items():
                k = data["stayed"][s][a]
                if not 0 <= k <= n:
                    raise ValueError(f"truth: height {s} action {a}: {k} stayed of {n} trials")
                table.trials[int(s), int(a) - 1] = n
                table.stayed[int(s), int(a) - 1] = k
        return table

    def save(self, path: Path) -> None:
        path.write_text(json.dumps(self.to_json(), indent=1) + "\n", encoding="utf-8")

    @classmethod
    def load(cls, path: Path) -> TruthTable:
        return cls.from_json(json.loads(Path(path).read_text(encoding="utf-8")))


def kl_to_truth(truth: TruthTable, learned_margin: np.ndarray) -> dict[int, float]:
    """KL(measured truth || learned model) per height, averaged over the pairs that can occur
    and were measured; heights with no such pair are left out. The learned P(stable) is read
    from the margin as in section 3.2, clipped by MARGIN_EPS."""
    p = truth.p_stable()
    q = stability_probability(np.asarray(learned_margin)[: truth.n_states], MARGIN_EPS)
    out = {}
    for s in range(truth.n_states):
        measured = ~np.isnan(p[s])
        if measured.any():
            out[s] = float(bernoulli_kl(p[s, measured], q[s, measured]).mean())
    return out


# -- the measurement: which outcome a placement had --------------------------------------


@dataclass(frozen=True)
class TrueBlock:
    """What the outcome needs of one block of sim/ground_truth."""

    id: str
    x: float
    y: float
    z: float
    level: int
    flat: bool = True  # on its top or bottom face (not on a side, not leaning)


def placement_stayed(before: Sequence[TrueBlock], after: Sequence[TrueBlock], placed: str,
                     stack: Sequence[str], moved_tol_m: float = 0.01) -> bool:
    """The placed block lies flat on top of the stack it was placed upon (level height + 1),
    and the stack's blocks are still where they were: the paper's 'stable'. On the table
    (empty stack) a placement stays when the block lies flat at level 1. A block that came to
    rest on its side fell over, on the stack or not (the judge says the same)."""
    now = {b.id: b for b in after}
    then = {b.id: b for b in before}
    block = now.get(placed)
    if block is None or block.level != len(stack) + 1 or not block.flat:
        return False
    for bid in stack:
        a, b = then.get(bid), now.get(bid)
        if a is None or b is None or b.level != a.level:
            return False
        if np.hypot(b.x - a.x, b.y - a.y) > moved_tol_m or abs(b.z - a.z) > moved_tol_m:
            return False
    return True


def truth_schedule(trials: int, max_height: int, n_actions: int, table_action: int = 1
                   ) -> list[tuple[int, int]]:
    """The (height, action) pairs to measure, `trials` rounds of every pair that can occur,
    round by round (so an interrupted measurement is balanced)."""
    pairs = [(0, table_action)] + [(h, a) for h in range(1, max_height + 1)
                                   for a in range(1, n_actions + 1)]
    return [pair for _ in range(trials) for pair in pairs]
