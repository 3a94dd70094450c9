"""Measures of what the agent learned and how it explored (section 3.2)."""

from __future__ import annotations

import numpy as np

# Learned margins are clipped to [-1 + EPS, 1 - EPS] before they are read as probabilities, so a
# margin outside [-1, 1] (possible between projections) gives a large but finite divergence.
MARGIN_EPS = 1e-2


def stability_probability(margin: np.ndarray, eps: float = 0.0) -> np.ndarray:
    """P(y = +1 | x) = (1 + margin) / 2 under the paper's label noise model."""
    return (1.0 + np.clip(margin, -1.0 + eps, 1.0 - eps)) / 2.0


def bernoulli_kl(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """KL(Bernoulli(p) || Bernoulli(q)) elementwise, with 0 log 0 = 0."""
    p, q = np.asarray(p, dtype=float), np.asarray(q, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.where(p > 0, p * np.log(p / q), 0.0)
        b = np.where(p < 1, (1 - p) * np.log((1 - p) / (1 - q)), 0.0)
    return a + b


def model_kl(true_margin: np.ndarray, learned_margin: np.ndarray) -> np.ndarray:
    """KL(true || learned) per height, averaged uniformly over the actions (last axis)."""
    p = stability_probability(true_margin)
    q = stability_probability(learned_margin, MARGIN_EPS)
    return bernoulli_kl(p, q).mean(axis=-1)


def cumulative_by_state(
    states: np.ndarray, selected: np.ndarray, n_states: int, at: np.ndarray
) -> np.ndarray:
    """Count, at each experiment count in `at`, how many selected experiments so far had
    each state.

    Returns (len(at), n_states): the curves of Figure 4 (direct or planned experience).
    """
    onehot = np.zeros((len(states) + 1, n_states), dtype=np.int64)
    onehot[np.arange(1, len(states) + 1), states] = selected
    return np.cumsum(onehot, axis=0)[np.asarray(at)]


def experience_histogram(
    states: np.ndarray, actions: np.ndarray, state: int, n_actions: int, upto: int
) -> np.ndarray:
    """How often each action was tried at `state` in the first `upto` experiments (Figures 6-8)."""
    mask = states[:upto] == state
    return np.bincount(actions[:upto][mask], minlength=n_actions)


def direct_exploration_end(
    states: np.ndarray, modes: np.ndarray, state: int, query: int = 0
) -> int:
    """The experiment after the last direct query at `state` (Figure 4's dotted lines); -1: none."""
    hits = np.flatnonzero((states == state) & (modes == query))
    return int(hits[-1]) + 1 if len(hits) else -1
