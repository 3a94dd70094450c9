"""The exploration methods the paper's discussion contrasts itself with, as registry strategies.

- lp: learning progress (Oudeyer et al. 2007, IAC/R-IAC): a pair's phantom reward is the recent
  decrease of its prediction error over a sliding window; planned every step.
- variance: the predictive variance of the outcome as phantom reward, without the query
  condition (the variance-based approach of Hester and Stone 2012 that section 4 contrasts with:
  a noisy outcome keeps a high variance however confident the model is); planned every step.
- rmax: count-based optimism (R-max, Brafman and Tennenholtz 2003): a pair is unknown until it
  was tried `tries` times; Algorithm 1 with that count in place of the query condition.
- egreedy: epsilon-greedy: the planned (phantom query reward) choice, or with probability
  `epsilon` a uniformly random instance of the setting.

core.strategies registers them beside the paper's methods; `--strategies` selects them.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from .environment import Setting, ShuffledSetting
from .explorer import QUERY, RANDOM, Choice, PlanningStrategy
from .planner import RewardTable, clip_margin


class ReplannedEveryStep(PlanningStrategy):
    """Solves the plan anew every step and follows it (no query condition of its own): lp and
    variance, which differ only in their phantom reward."""

    def choose(self, setting: Setting | ShuffledSetting, step: int) -> Choice:
        self.planner.solve()
        return self.planned(setting)


class LearningProgress(ReplannedEveryStep):
    """IAC-style learning progress per (height, action) pair, planned on as phantom reward.

    The error of an example is |label - clipped margin| / 2 in [0, 1], measured before the
    model learns it. With the last 2 * window errors of a pair, progress is
    max(0, mean(older window) - mean(recent window)); a pair with fewer errors is maximally
    promising (1), so that every pair gets a window of experience first.
    """

    name = "lp"
    window: ClassVar[int] = 5

    def setup(self) -> None:
        bank = self.bank
        self.errors = np.zeros((bank.n_states, bank.n_actions, 2 * self.window))
        self.counts = np.zeros((bank.n_states, bank.n_actions), dtype=np.int64)
        bank.listeners.append(self._learned)

    def phantom_reward(self) -> RewardTable:
        return self.progress

    def _learned(self, state: int, action: int, label: float, margin: float) -> None:
        error = abs(label - float(clip_margin(margin))) / 2.0
        self.errors[state, action, self.counts[state, action] % (2 * self.window)] = error
        self.counts[state, action] += 1

    def progress(self, rows: np.ndarray) -> np.ndarray:
        """The phantom reward of `rows`: recent decrease of the prediction error."""
        w = self.window
        counts = self.counts[rows]
        # ring positions, newest first: (count - 1 - i) mod 2w
        order = (counts[..., None] - 1 - np.arange(2 * w)) % (2 * w)
        errors = np.take_along_axis(self.errors[rows], order, axis=-1)
        decrease = errors[..., w:].mean(axis=-1) - errors[..., :w].mean(axis=-1)
        reward = np.where(counts >= 2 * w, np.maximum(decrease, 0.0), 1.0)
        reward[self.bank.slot[rows] < 0] = 0.0  # nothing to learn where there is no predictor
        return reward


class Variance(ReplannedEveryStep):
    """Predictive variance of the +-1 outcome, 1 - margin^2, as phantom reward; no query
    condition, re-planned every step."""

    name = "variance"
    reward = "variance"


class RMax(PlanningStrategy):
    """R-max-like counts: a pair is unknown until tried `tries` times. The first available
    unknown pair is tried directly; otherwise the plan goes where the unknown pairs are."""

    name = "rmax"
    tries: ClassVar[int] = 5

    def setup(self) -> None:
        if self.tries < 1:
            raise ValueError(f"tries must be >= 1, got {self.tries}")
        bank = self.bank
        self.counts = np.zeros((bank.n_states, bank.n_actions), dtype=np.int64)
        learned = bank.slot >= 0
        learned[self.top:] = False
        self.unknown = np.zeros((bank.n_states, bank.n_actions), dtype=bool)
        self.unknown[learned] = True
        bank.listeners.append(self._learned)

    def phantom_reward(self) -> RewardTable:
        return self.optimism

    def _learned(self, state: int, action: int, label: float, margin: float) -> None:
        self.counts[state, action] += 1
        if self.counts[state, action] >= self.tries:
            self.unknown[state, action] = False

    def optimism(self, rows: np.ndarray) -> np.ndarray:
        return self.unknown[rows].astype(float)

    def choose(self, setting: Setting | ShuffledSetting, step: int) -> Choice:
        found = setting.first_where(self.unknown)
        if found is not None:
            index, state, action = found
            return Choice(state, action, QUERY, index)
        self.planner.solve()
        return self.planned(setting)


class EpsilonGreedy(PlanningStrategy):
    """The planned choice (phantom query reward), or a random instance with prob. epsilon."""

    name = "egreedy"
    epsilon: ClassVar[float] = 0.1

    def choose(self, setting: Setting | ShuffledSetting, step: int) -> Choice:
        if self.rng.random() < self.epsilon:
            index, state, action = setting.random_instance(self.rng)
            return Choice(state, action, RANDOM, index)
        self.planner.solve()
        return self.planned(setting)


BASELINES: tuple[type[PlanningStrategy], ...] = (LearningProgress, Variance, RMax, EpsilonGreedy)
