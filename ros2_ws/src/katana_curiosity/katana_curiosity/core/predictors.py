"""A bank of modified-RLS predictors, one per height, with the query condition of Eq. 2.

Every instance in this product is a (state, action) pair whose feature vector x depends on the
action only (one-hot action plus a bias, both in the paper's simulation and on its robot). The bank
therefore keeps, for every learned height and every action, the margin w.x, the quadratic form
c = x^T A^-1 x, the confidence chi and the query flag up to date incrementally: an update touches
one height, and a query is a table look-up. Arbitrary feature vectors are still supported by
`evaluate` for analysis and tests.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np


def one_hot_with_bias(n_actions: int) -> np.ndarray:
    """Feature table of the paper: row a is the one-hot code of action a followed by a bias of 1."""
    table = np.zeros((n_actions, n_actions + 1))
    table[np.arange(n_actions), np.arange(n_actions)] = 1.0
    table[:, -1] = 1.0
    return table


def exploration_horizon(examples: np.ndarray | int) -> np.ndarray | float:
    """h = log(1 + i), with i the index of the predictor's next example (examples seen + 1).

    The paper's i counts the queried examples of one classifier and starts at 1 (A_1 = I), so an
    untrained predictor has h = log 2 > 0 and its first instance is unknown.
    """
    return np.log(2.0 + np.asarray(examples, dtype=float))


#: The query condition's scale alpha and threshold theta, as the paper's section 3 states them:
#: alpha = 1; theta = 0.01 for the simulated blocks world (section 3.2), 0.1 on the robot (3.3).
ALPHA = 1.0
THETA_ABSTRACT = 0.01
THETA_ROBOT = 0.1
#: The discount factor of the plan, as the paper's section 3 states it: gamma = 0.95.
GAMMA = 0.95

# Called by PredictorBank.update for every learned example: (state, action, label, margin before).
UpdateListener = Callable[[int, int, float, float], None]


@dataclass(frozen=True)
class QueryRule:
    """Eq. 2: query when chi > |margin| and chi > theta, with chi = alpha sqrt(c h)."""

    alpha: float = ALPHA
    theta: float = THETA_ABSTRACT

    def __post_init__(self) -> None:
        if not (math.isfinite(self.alpha) and self.alpha > 0.0):
            raise ValueError(f"alpha must be a finite number > 0, got {self.alpha!r}")
        if not (math.isfinite(self.theta) and 0.0 <= self.theta <= 1.0):
            raise ValueError(f"theta must be in [0, 1], got {self.theta!r}")

    def confidence(self, c: np.ndarray, h: np.ndarray | float) -> np.ndarray:
        return self.alpha * np.sqrt(np.maximum(c, 0.0) * h)

    def is_query(self, margin: np.ndarray, chi: np.ndarray) -> np.ndarray:
        return (chi > np.abs(margin)) & (chi > self.theta)


class PredictorBank:
    """One modified-RLS classifier (Algorithm 2) per learned height.

    States that are not in `heights` (for example the table in the paper's simulation, where a
    placement always succeeds) have no predictor: their margins read as 0 and they are never
    unknown.
    """

    def __init__(
        self,
        heights: Sequence[int],
        features: np.ndarray,
        rule: QueryRule | None = None,
        n_states: int | None = None,
    ) -> None:
        heights = [int(h) for h in heights]
        if not heights or len(set(heights)) != len(heights) or min(heights) < 0:
            raise ValueError(f"heights must be distinct non-negative integers, got {heights}")
        features = np.asarray(features, dtype=float)
        if features.ndim != 2 or features.shape[0] < 1 or not np.all(np.isfinite(features)):
            raise ValueError("features must be a finite (n_actions, d) array")
        self.heights = np.asarray(heights)
        self.n_states = int(n_states if n_states is not None else max(heights) + 1)
        if self.n_states <= max(heights):
            raise ValueError(f"n_states must exceed the largest height, got {self.n_states}")
        self.features = features
        self.n_actions, self.dim = features.shape
        self.rule = rule or QueryRule()
        # slot[s] is the row of state s in the per-height arrays, -1 for states without predictor
        self.slot = np.full(self.n_states, -1, dtype=int)
        self.slot[self.heights] = np.arange(len(heights))
        n = len(heights)
        self.a_inv = np.tile(np.eye(self.dim), (n, 1, 1))
        self.w = np.zeros((n, self.dim))
        self.examples = np.zeros(n, dtype=np.int64)
        # Per state and action, over all n_states (rows of unlearned states stay neutral).
        self.margin = np.zeros((self.n_states, self.n_actions))
        self.quad = np.zeros((self.n_states, self.n_actions))
        self.chi = np.zeros((self.n_states, self.n_actions))
        self.unknown = np.zeros((self.n_states, self.n_actions), dtype=bool)
        # Bumped whenever a state's row changes, so that planners rebuild only what changed.
        self.version = np.zeros(self.n_states, dtype=np.int64)
        # Strategies that learn from outcomes themselves (learning progress, counts) listen here.
        self.listeners: list[UpdateListener] = []
        for s in self.heights:
            self._refresh(int(s))

    # -- learning ---------------------------------------------------------------------------

    def update(self, state: int, action: int, label: float) -> bool:
        """Learn one labelled instance; returns False (and learns nothing) for unlearned states."""
        k = self.slot[state]
        if k < 0:
            return False
        x = self.features[action]
        a_inv = self.a_inv[k]
        w = self.w[k]
        b = a_inv @ x
        c = float(x @ b)
        margin = float(w @ x)
        for listener in self.listeners:
            listener(state, action, label, margin)
        if abs(margin) > 1.0:  # projection step: bring the margin on x back to +-1
            w -= math.copysign((abs(margin) - 1.0) / c, margin) * b
            margin = math.copysign(1.0, margin)
        scale = 1.0 / (1.0 + c)
        a_inv -= b[:, None] * (b * scale)
        w += ((label - margin) * scale) * b  # in place: w is the bank's row k
        self.examples[k] += 1
        # Sherman-Morrison on every action's quadratic form at once: x_a^T A^-1 x_a shrinks by
        # (x_a . b)^2 / (1 + c). Exact up to rounding; `_refresh` recomputes it from scratch.
        fb = self.features @ b
        fb *= fb
        fb *= scale
        self.quad[state] -= fb
        self.margin[state] = self.features @ w
        self._flags(state, k)
        self.version[state] += 1
        return True

    def _refresh(self, state: int) -> None:
        k = self.slot[state]
        f = self.features
        self.margin[state] = f @ self.w[k]
        self.quad[state] = np.maximum(np.einsum("ad,de,ae->a", f, self.a_inv[k], f), 0.0)
        self._flags(state, k)
        self.version[state] += 1

    def _flags(self, state: int, k: int) -> None:
        # chi = alpha sqrt(c h) with h = exploration_horizon(examples), scalar fast path
        scale = self.rule.alpha * math.sqrt(math.log(2.0 + float(self.examples[k])))
        chi = np.sqrt(self.quad[state])
        chi *= scale
        self.chi[state] = chi
        self.unknown[state] = (chi > np.abs(self.margin[state])) & (chi > self.rule.theta)

    # -- evaluation -------------------------------------------------------------------------

    def evaluate(
        self, states: np.ndarray, x: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Margins, confidences and query flags of arbitrary instances, all at once.

        states: (n,) learned heights; x: (n, d) feature vectors.
        """
        k = self.slot[np.asarray(states)]
        if np.any(k < 0):
            raise ValueError("evaluate needs states that have a predictor")
        x = np.asarray(x, dtype=float)
        margin = np.einsum("nd,nd->n", self.w[k], x)
        quad = np.einsum("nd,nde,ne->n", x, self.a_inv[k], x)
        chi = self.rule.confidence(quad, exploration_horizon(self.examples[k]))
        return margin, chi, self.rule.is_query(margin, chi)

    def weights(self, state: int) -> np.ndarray:
        k = self.slot[state]
        if k < 0:
            raise KeyError(f"state {state} has no predictor")
        return self.w[k].copy()

    # -- persistence (npz, no pickle) -------------------------------------------------------

    def state_dict(self) -> dict[str, np.ndarray]:
        return {
            "heights": self.heights.copy(),
            "features": self.features.copy(),
            "a_inv": self.a_inv.copy(),
            "w": self.w.copy(),
            "examples": self.examples.copy(),
            "alpha": np.array(self.rule.alpha),
            "theta": np.array(self.rule.theta),
            "n_states": np.array(self.n_states),
        }

    @classmethod
    def from_state_dict(cls, data: dict[str, np.ndarray]) -> PredictorBank:
        bank = cls(
            heights=data["heights"].tolist(),
            features=data["features"],
            rule=QueryRule(float(data["alpha"]), float(data["theta"])),
            n_states=int(data["n_states"]),
        )
        bank.a_inv[:] = data["a_inv"]
        bank.w[:] = data["w"]
        bank.examples[:] = data["examples"]
        for s in bank.heights:
            bank._refresh(int(s))
        return bank
