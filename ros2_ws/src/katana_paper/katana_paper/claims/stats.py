"""The statistics behind a claim's verdict: a bootstrap confidence interval over seeds, the
verdict it gives, a rank test, and how many seeds an undecided claim would need.

The interval is scipy.stats.bootstrap's percentile interval with every group of seeds (every
strategy) resampled on its own (`paired=False`): the stratified bootstrap over runs that
rliable (Agarwal et al. 2021) uses, with the strategies as strata. The rank test is
scipy.stats.mannwhitneyu; its U statistic over n1 * n2 is rliable's "probability of
improvement". Written here by hand, because neither scipy nor the project's dependencies
have it: the three-way verdict (a rule on the interval) and the seeds-to-decide estimate.
scipy.stats.power simulates the power of a test at a given sample size but solves for none,
and statsmodels' solvers are for standardised mean differences, not for a bootstrap
statistic such as a ratio or a minimum over strategies; the estimate below is the normal
approximation n = n_obs (z_(1-a/2) + z_power)^2 (se / delta)^2 from the bootstrap standard
error, which scales as 1 / sqrt(n).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

#: the confidence level of every interval
LEVEL = 0.95
#: bootstrap resamples per claim
RESAMPLES = 10_000
#: the seed of each claim's resampling (each claim starts its own generator from it)
SEED = 0
#: the power the seeds-to-decide estimate is for
POWER = 0.8
#: the fewest seeds per group a verdict is given from: a percentile bootstrap over two seeds
#: draws only three distinct means and its interval is the two values themselves
MIN_SEEDS = 3

PASS = "PASS"
FAIL = "FAIL"
INCONCLUSIVE = "INCONCLUSIVE"
VERDICTS = (PASS, FAIL, INCONCLUSIVE)

Statistic = Callable[..., np.ndarray]


@dataclass(frozen=True)
class Claimed:
    """What a claim says of its statistic: above `null` ("greater"), below it ("less"), or
    inside `bounds` ("within": an equivalence claim, such as "closely followed by")."""

    kind: str
    null: float = 0.0
    bounds: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.kind not in ("greater", "less", "within"):
            raise ValueError(f"kind must be greater, less or within, got {self.kind!r}")
        if self.kind == "within" and (self.bounds is None or self.bounds[0] > self.bounds[1]):
            raise ValueError(f"a 'within' claim needs bounds lo <= hi, got {self.bounds!r}")

    def text(self) -> str:
        """'> 0', '< 0.33' or 'within [-0.1, 0.1]'."""
        if self.kind == "within":
            lo, hi = self.bounds  # type: ignore[misc]
            return f"within [{lo:g}, {hi:g}]"
        return f"{'>' if self.kind == 'greater' else '<'} {self.null:.3g}"


def verdict(ci: tuple[float, float] | None, claimed: Claimed) -> str:
    """PASS when the interval excludes the null on the claimed side (for "within": lies inside
    the bounds), FAIL when it excludes it on the other side (for "within": lies wholly outside
    them, the claimed effect ruled out), INCONCLUSIVE otherwise or without an interval."""
    if ci is None or not all(math.isfinite(v) for v in ci):
        return INCONCLUSIVE
    lo, hi = ci
    if claimed.kind == "within":
        b_lo, b_hi = claimed.bounds  # type: ignore[misc]
        if b_lo <= lo and hi <= b_hi:
            return PASS
        if hi < b_lo or lo > b_hi:
            return FAIL
        return INCONCLUSIVE
    above, below = lo > claimed.null, hi < claimed.null
    if claimed.kind == "greater":
        return PASS if above else FAIL if below else INCONCLUSIVE
    return PASS if below else FAIL if above else INCONCLUSIVE


@dataclass(frozen=True)
class Estimate:
    """A statistic over groups of per-seed values, with its bootstrap interval and standard
    error (None with fewer than two seeds in a group)."""

    effect: float
    ci: tuple[float, float] | None
    se: float | None
    seeds: tuple[int, ...]


def bootstrap_estimate(samples: Sequence[Sequence[float]], statistic: Statistic,
                       resamples: int = RESAMPLES, seed: int = SEED,
                       level: float = LEVEL) -> Estimate:
    """`statistic(*samples, axis=-1)` and its percentile interval, each sample resampled on
    its own with scipy.stats.bootstrap (vectorised, `resamples` draws, a generator seeded with
    `seed`). A sample of fewer than two values gives no interval."""
    arrays = [np.asarray(s, dtype=float) for s in samples]
    if not arrays or any(a.ndim != 1 or len(a) == 0 for a in arrays):
        raise ValueError("every sample needs at least one value")
    if not all(np.isfinite(a).all() for a in arrays):
        raise ValueError("samples must be finite")
    effect = float(statistic(*arrays, axis=-1))
    seeds = tuple(len(a) for a in arrays)
    if min(seeds) < 2:
        return Estimate(effect, None, None, seeds)
    res = bootstrap_result(arrays, statistic, resamples, seed, level)
    ci = (float(res.confidence_interval.low), float(res.confidence_interval.high))
    return Estimate(effect, ci, float(res.standard_error), seeds)


def bootstrap_result(arrays: Sequence[np.ndarray], statistic: Statistic, resamples: int,
                     seed: int, level: float, paired: bool = False):
    """scipy's BootstrapResult (interval, distribution, standard error) for the arrays: each
    resampled on its own, or with `paired` the same indices drawn for all (equal lengths)."""
    return stats.bootstrap(tuple(arrays), statistic, n_resamples=resamples, vectorized=True,
                           paired=paired, axis=-1, confidence_level=level,
                           method="percentile", rng=np.random.default_rng(seed))


def mean_band(curves: np.ndarray, resamples: int = 2_000, seed: int = SEED,
              level: float = LEVEL) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A learning curve's mean over seeds and its bootstrap interval at every point: `curves`
    is (seeds, points); returns (mean, low, high), each (points,). With fewer than three seeds
    (MIN_SEEDS) the band is the range of the seeds: the percentile bootstrap of two values is
    the two values themselves. Points where a seed has no value use the seeds that have one."""
    curves = np.asarray(curves, dtype=float)
    if curves.ndim != 2 or curves.shape[0] == 0:
        raise ValueError("curves must be (seeds, points) with at least one seed")
    mean = np.full(curves.shape[1], np.nan)
    low, high = mean.copy(), mean.copy()
    finite = np.isfinite(curves)
    for count in np.unique(finite.sum(axis=0)):
        if count == 0:
            continue
        cols = np.flatnonzero(finite.sum(axis=0) == count)
        # the seeds with a value, column by column: (count, len(cols))
        values = np.array([curves[finite[:, c], c] for c in cols]).T
        mean[cols] = values.mean(axis=0)
        if count < MIN_SEEDS:
            low[cols], high[cols] = values.min(axis=0), values.max(axis=0)
            continue
        res = stats.bootstrap((values,), np.mean, n_resamples=resamples, vectorized=True,
                              axis=0, confidence_level=level, method="percentile",
                              rng=np.random.default_rng(seed))
        low[cols], high[cols] = res.confidence_interval.low, res.confidence_interval.high
    return mean, low, high


def seeds_to_decide(estimate: Estimate, claimed: Claimed, power: float = POWER,
                    level: float = LEVEL) -> int | None:
    """Seeds per group that would decide an undecided claim, a normal approximation: with the
    observed effect and the bootstrap standard error scaled by sqrt(n_obs / n), the n at which
    the interval clears the nearest decision point (the null, or a bound of a "within" claim)
    with probability `power`. None when it cannot be estimated (no interval, no spread, or an
    effect exactly on the decision point); at least one more than the seeds at hand."""
    if estimate.ci is None or not estimate.se or not math.isfinite(estimate.se):
        return None
    points = claimed.bounds if claimed.kind == "within" else (claimed.null,)
    delta = min(abs(estimate.effect - p) for p in points)  # type: ignore[union-attr]
    if delta == 0 or not math.isfinite(delta):
        return None
    z = stats.norm.ppf(1 - (1 - level) / 2) + stats.norm.ppf(power)
    n_obs = min(estimate.seeds)
    needed = math.ceil(n_obs * (z * estimate.se / delta) ** 2)
    return max(needed, n_obs + 1)


def rank_test(x: Sequence[float], y: Sequence[float], claimed: Claimed
              ) -> tuple[float, float] | tuple[None, None]:
    """For a claim on mean(x) - mean(y): the probability that a seed of x beats a seed of y in
    the claimed direction (ties count half; rliable's probability of improvement) and the
    one-sided Mann-Whitney U p-value of that direction. (None, None) for a "within" claim or
    fewer than two seeds in a group."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    if claimed.kind == "within" or len(x) < 2 or len(y) < 2:
        return None, None
    res = stats.mannwhitneyu(x, y, alternative=claimed.kind)
    share = float(res.statistic) / (len(x) * len(y))  # P(X > Y) + P(X = Y) / 2
    return (share if claimed.kind == "greater" else 1.0 - share), float(res.pvalue)


# -- statistics (vectorised: resamples along the last axis) ---------------------------------


def mean(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """The mean of one group."""
    return np.mean(x, axis=axis)


def difference(x: np.ndarray, y: np.ndarray, axis: int = -1) -> np.ndarray:
    """mean(x) - mean(y)."""
    return np.mean(x, axis=axis) - np.mean(y, axis=axis)


def relative_difference(x: np.ndarray, y: np.ndarray, axis: int = -1) -> np.ndarray:
    """(mean(x) - mean(y)) / mean(y)."""
    base = np.mean(y, axis=axis)
    return (np.mean(x, axis=axis) - base) / base


def others_min_minus_first(first: np.ndarray, *others: np.ndarray,
                           axis: int = -1) -> np.ndarray:
    """min over the other groups' means, minus the first group's mean: > 0 when the first
    group is lowest of all."""
    return np.min([np.mean(o, axis=axis) for o in others], axis=0) - np.mean(first, axis=axis)


def first_minus_others_max(first: np.ndarray, *others: np.ndarray,
                           axis: int = -1) -> np.ndarray:
    """The first group's mean minus the max over the other groups' means: > 0 when the first
    group is highest of all."""
    return np.mean(first, axis=axis) - np.max([np.mean(o, axis=axis) for o in others], axis=0)
