"""Planning with phantom rewards (paper section 2.4): the MDP over heights, solved by LSPI.

States are stack heights 0..top, where `top` (one above the highest height a block can be placed
on) is absorbing. Transitions come from the predictors' margins:
P(s+1 | s, a) = (1 + margin) / 2, and the rest, (1 - margin) / 2, spread evenly over the heights
a stack can topple to (1..s; for s = 0 it stays 0). States without a predictor (the table in the
paper's simulation) move to s+1 with certainty. Rewards are phantom: 1 where the query condition
holds (Q1, Q10), or the confidence chi itself (Conf).

The policy is found by LSPI (Lagoudakis and Parr 2003) with LSTDQ-Model: the model is known, so
each LSTDQ solve weighs every state-action pair once with its exact expected next features.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Protocol

import numpy as np

from .predictors import GAMMA, PredictorBank

# Values closer than this are ties. Floating-point noise (a BLAS kernel summing two identical
# rows in different orders) must not decide between equally good actions or heights; ties go to
# the first action and to the highest height, in the NumPy planner and the compiled fast path.
TIE_TOLERANCE = 1e-12

REWARD_KINDS = ("query", "confidence", "variance")

# A phantom reward computed by a strategy: rows of states in, R[rows] (len(rows), n_actions) out.
RewardTable = Callable[[np.ndarray], np.ndarray]


@dataclass
class HeightMDP:
    """A finite MDP: P[s, a, s'] and R[s, a]; the last state is absorbing with no reward."""

    transitions: np.ndarray
    rewards: np.ndarray
    gamma: float = GAMMA

    @property
    def n_states(self) -> int:
        return self.transitions.shape[0]

    @property
    def n_actions(self) -> int:
        return self.transitions.shape[1]


def clip_margin(margin: np.ndarray) -> np.ndarray:
    return np.clip(margin, -1.0, 1.0)


@lru_cache(maxsize=16)
def _height_structure(top: int) -> tuple[np.ndarray, np.ndarray]:
    """Where a placement on height s goes: up[s] if it stays, down[s] (spread) if it falls."""
    n = top + 1
    up, down = np.zeros((n, n)), np.zeros((n, n))
    for s in range(top):
        up[s, s + 1] = 1.0
        low = 1 if s >= 1 else 0
        down[s, low : s + 1] = 1.0 / (s + 1 - low)
    up.flags.writeable = down.flags.writeable = False
    return up, down


def _stability(bank: PredictorBank, top: int, rows: np.ndarray) -> np.ndarray:
    """P(s+1 | s, a) for the given rows of states 0..top."""
    stable = (1.0 + clip_margin(bank.margin[rows])) / 2.0
    stable[bank.slot[rows] < 0] = 1.0  # no predictor: a placement there always succeeds
    stable[rows == top] = 0.0  # absorbing: down[top] is all zero, so the row has no mass
    return stable


def transition_model(bank: PredictorBank, top: int, rows: np.ndarray | None = None) -> np.ndarray:
    """P[s, a, s'] over states 0..top from the bank's margins (section 2.4), for `rows` of s."""
    up, down = _height_structure(top)
    rows = np.arange(top + 1) if rows is None else np.asarray(rows)
    stable = _stability(bank, top, rows)
    return (
        stable[:, :, None] * up[rows][:, None, :]
        + (1.0 - stable)[:, :, None] * down[rows][:, None, :]
    )


def phantom_rewards(
    bank: PredictorBank, top: int, kind: str = "query", rows: np.ndarray | None = None
) -> np.ndarray:
    """R[s, a]: 1 where the query condition holds ("query"), chi itself ("confidence"), or the
    predictive variance of the +-1 label, 1 - margin^2 ("variance", Hester and Stone 2012 style:
    large for a noisy outcome however confident the model is)."""
    rows = np.arange(top + 1) if rows is None else np.asarray(rows)
    learned = (bank.slot[rows] >= 0) & (rows < top)
    r = np.zeros((len(rows), bank.n_actions))
    if kind == "query":
        r[learned] = bank.unknown[rows[learned]]
    elif kind == "confidence":
        r[learned] = bank.chi[rows[learned]]
    elif kind == "variance":
        r[learned] = 1.0 - clip_margin(bank.margin[rows[learned]]) ** 2
    else:
        raise ValueError(f"unknown reward kind {kind!r}: use one of {', '.join(REWARD_KINDS)}")
    return r


def build_mdp(
    bank: PredictorBank, top: int, gamma: float = GAMMA, reward: str = "query"
) -> HeightMDP:
    return HeightMDP(transition_model(bank, top), phantom_rewards(bank, top, reward), gamma)


# -- basis functions -------------------------------------------------------------------------


class Basis(Protocol):
    """phi(s, a) for LSTDQ; `dim` features per pair."""

    dim: int

    def __call__(self, states: np.ndarray, actions: np.ndarray) -> np.ndarray: ...


@dataclass
class TabularBasis:
    """One indicator per (state, action): LSTDQ is then exact policy evaluation."""

    n_states: int
    n_actions: int
    dim: int = field(init=False)

    def __post_init__(self) -> None:
        self.dim = self.n_states * self.n_actions

    def __call__(self, states: np.ndarray, actions: np.ndarray) -> np.ndarray:
        phi = np.zeros((len(states), self.dim))
        phi[np.arange(len(states)), np.asarray(states) * self.n_actions + actions] = 1.0
        return phi


@dataclass
class PolynomialBasis:
    """A compact basis: per action, a polynomial in the normalised height (large state spaces)."""

    n_states: int
    n_actions: int
    degree: int = 2
    dim: int = field(init=False)

    def __post_init__(self) -> None:
        self.dim = self.n_actions * (self.degree + 1)

    def __call__(self, states: np.ndarray, actions: np.ndarray) -> np.ndarray:
        z = np.asarray(states, dtype=float) / max(self.n_states - 1, 1)
        powers = z[:, None] ** np.arange(self.degree + 1)
        phi = np.zeros((len(z), self.dim))
        cols = np.asarray(actions)[:, None] * (self.degree + 1) + np.arange(self.degree + 1)
        phi[np.arange(len(z))[:, None], cols] = powers
        return phi


# -- LSTDQ-Model and LSPI --------------------------------------------------------------------


def lstdq_model(mdp: HeightMDP, basis: Basis, policy: np.ndarray) -> np.ndarray:
    """Weights of Q^policy projected on the basis, from the known model (uniform over pairs)."""
    ns, na = mdp.n_states, mdp.n_actions
    s_all = np.repeat(np.arange(ns), na)
    a_all = np.tile(np.arange(na), ns)
    phi = basis(s_all, a_all)  # (ns*na, k)
    phi_next_state = basis(np.arange(ns), policy)  # (ns, k): phi(s', pi(s'))
    expected_next = mdp.transitions.reshape(ns * na, ns) @ phi_next_state
    a_mat = phi.T @ (phi - mdp.gamma * expected_next)
    b_vec = phi.T @ mdp.rewards.reshape(-1)
    return np.linalg.lstsq(a_mat, b_vec, rcond=None)[0]


def q_from_weights(mdp: HeightMDP, basis: Basis, weights: np.ndarray) -> np.ndarray:
    ns, na = mdp.n_states, mdp.n_actions
    s_all = np.repeat(np.arange(ns), na)
    a_all = np.tile(np.arange(na), ns)
    return (basis(s_all, a_all) @ weights).reshape(ns, na)


def evaluate_tabular(mdp: HeightMDP, policy: np.ndarray) -> np.ndarray:
    """Q^policy exactly, through the state-space linear system.

    This is what LSTDQ-Model computes with a tabular basis (the test suite checks the two agree);
    solving for V over states instead of Q over pairs keeps planning within microseconds.
    """
    ns = mdp.n_states
    idx = np.arange(ns)
    p_pi = mdp.transitions[idx, policy]
    v = np.linalg.solve(np.eye(ns) - mdp.gamma * p_pi, mdp.rewards[idx, policy])
    return mdp.rewards + mdp.gamma * (mdp.transitions @ v)


def first_best(q: np.ndarray) -> np.ndarray:
    """Per row, the first action within TIE_TOLERANCE of the row's maximum."""
    return np.argmax(q >= q.max(axis=-1, keepdims=True) - TIE_TOLERANCE, axis=-1)


@dataclass
class LSPIResult:
    q: np.ndarray
    policy: np.ndarray
    iterations: int


def lspi(
    mdp: HeightMDP,
    basis: Basis | None = None,
    initial_policy: np.ndarray | None = None,
    max_iterations: int = 50,
    feasible: np.ndarray | None = None,
) -> LSPIResult:
    """Policy iteration with LSTDQ-Model evaluation, warm-started from `initial_policy`.

    feasible[s, a] False marks pairs that cannot occur (e.g. any action but "no overlap" on
    the table): the policy never takes them and the returned Q is -inf there.
    """
    ns, na = mdp.n_states, mdp.n_actions
    if feasible is not None and not feasible.any(axis=1).all():
        raise ValueError("every state needs at least one feasible action")
    first_feasible = np.zeros(ns, dtype=int) if feasible is None else feasible.argmax(axis=1)
    policy = first_feasible.copy() if initial_policy is None else np.asarray(initial_policy).copy()
    if feasible is not None:
        policy = np.where(feasible[np.arange(ns), policy], policy, first_feasible)
    tabular = basis is None or isinstance(basis, TabularBasis)
    q = np.zeros((ns, na))
    for iteration in range(1, max_iterations + 1):
        if tabular:
            q = evaluate_tabular(mdp, policy)
        else:
            q = q_from_weights(mdp, basis, lstdq_model(mdp, basis, policy))
        if feasible is not None:
            q = np.where(feasible, q, -np.inf)
        # Keep the current action on ties so that policy iteration terminates.
        best = first_best(q)
        keep = q[np.arange(ns), policy] >= q[np.arange(ns), best] - TIE_TOLERANCE
        new_policy = np.where(keep, policy, best)
        if np.array_equal(new_policy, policy):
            return LSPIResult(q, policy, iteration)
        policy = new_policy
    return LSPIResult(q, policy, max_iterations)


def value_iteration(
    mdp: HeightMDP, tol: float = 1e-12, max_iterations: int = 100_000
) -> np.ndarray:
    """Optimal Q by value iteration: the independent reference the tests compare LSPI with."""
    q = np.zeros((mdp.n_states, mdp.n_actions))
    for _ in range(max_iterations):
        q_new = mdp.rewards + mdp.gamma * (mdp.transitions @ q.max(axis=1))
        if np.max(np.abs(q_new - q)) < tol:
            return q_new
        q = q_new
    return q


class Planner:
    """Chooses (s*, a*) among the available heights (section 2.2) from an LSPI plan.

    The plan is re-solved from the last policy, so a call after a small model change usually
    costs one or two policy evaluations.
    """

    def __init__(
        self,
        bank: PredictorBank,
        top: int,
        gamma: float = GAMMA,
        reward: str | RewardTable = "query",
        basis: Basis | None = None,
        feasible: np.ndarray | None = None,
    ) -> None:
        """reward: a kind of REWARD_KINDS, or a RewardTable (re-read for every row at each solve,
        since a strategy's own reward may change without the bank changing)."""
        if not 0.0 <= gamma < 1.0:
            raise ValueError(f"gamma must be in [0, 1), got {gamma}")
        if not 1 <= top < bank.n_states:
            raise ValueError(f"top must be in [1, {bank.n_states - 1}], got {top}")
        if not callable(reward) and reward not in REWARD_KINDS:
            raise ValueError(
                f"unknown reward kind {reward!r}: use one of {', '.join(REWARD_KINDS)}"
            )
        self.bank, self.top, self.gamma, self.reward, self.basis = bank, top, gamma, reward, basis
        if feasible is not None:
            feasible = np.asarray(feasible, dtype=bool)
            if feasible.shape != (top + 1, bank.n_actions):
                raise ValueError(f"feasible must have shape {(top + 1, bank.n_actions)}")
            feasible = feasible.copy()
            feasible[top] = True  # the absorbing state: its actions do nothing anyway
        self.feasible = feasible
        self.policy = (
            np.zeros(top + 1, dtype=int) if feasible is None else self.feasible.argmax(axis=1)
        )
        self.q = np.zeros((top + 1, bank.n_actions))
        self.calls = 0
        self._mdp: HeightMDP | None = None
        self._seen = np.full(top + 1, -1, dtype=np.int64)

    def set_feasible(self, feasible: np.ndarray) -> None:
        """Plan with a new table of what can occur (the rows whose entries changed get their
        phantom rewards recomputed at the next solve)."""
        feasible = np.asarray(feasible, dtype=bool).copy()
        feasible[self.top] = True
        if self.feasible is None or feasible.shape != self.feasible.shape:
            raise ValueError("set_feasible needs a planner made with a feasible table")
        if not feasible.any(axis=1).all():
            raise ValueError("every state needs at least one feasible action")
        changed = np.flatnonzero((feasible != self.feasible).any(axis=1))
        self._seen[changed] = -1
        self.feasible = feasible
        self.policy = np.where(feasible[np.arange(self.top + 1), self.policy], self.policy,
                               feasible.argmax(axis=1))

    def solve(self) -> np.ndarray:
        """Re-plan on the current model; only the MDP rows of heights that changed are rebuilt."""
        rows = np.flatnonzero(self.bank.version[: self.top + 1] != self._seen)
        custom = callable(self.reward)
        if self._mdp is None:
            self._mdp = HeightMDP(
                transition_model(self.bank, self.top),
                np.zeros((self.top + 1, self.bank.n_actions)),
                self.gamma,
            )
            rows = np.arange(self.top + 1)
        elif len(rows):
            self._mdp.transitions[rows] = transition_model(self.bank, self.top, rows)
        if custom:
            every = np.arange(self.top + 1)
            rewards = np.array(self.reward(every), dtype=float)
            rewards[self.top] = 0.0  # absorbing: nothing to gain there
            self._mdp.rewards[:] = rewards
        elif len(rows):
            self._mdp.rewards[rows] = phantom_rewards(self.bank, self.top, self.reward, rows)
        self._seen = self.bank.version[: self.top + 1].copy()
        if self.feasible is not None:
            self._mdp.rewards[~self.feasible] = 0.0  # no phantom reward for what cannot happen
        result = lspi(self._mdp, self.basis, self.policy, feasible=self.feasible)
        self.policy, self.q = result.policy, result.q
        self.calls += 1
        return self.q

    def choose(self, available: np.ndarray, q: np.ndarray | None = None) -> tuple[int, int]:
        """Best available state by V(s) = max_a Q(s, a) (ties: the higher), then its best action."""
        q = self.q if q is None else q
        available = np.asarray(available)
        values = q[available].max(axis=1)
        # Last maximum: among equally valuable heights, the higher one builds towards the unknown.
        near = values >= values.max() - TIE_TOLERANCE
        s = int(available[len(values) - 1 - int(np.argmax(near[::-1]))])
        return s, int(first_best(q[s]))
