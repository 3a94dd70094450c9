"""The MDP of section 2.4 and LSPI/LSTDQ-Model against value iteration."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_curiosity.core.planner import (
    HeightMDP,
    Planner,
    PolynomialBasis,
    TabularBasis,
    build_mdp,
    evaluate_tabular,
    lspi,
    lstdq_model,
    q_from_weights,
    transition_model,
    value_iteration,
)
from katana_curiosity.core.predictors import GAMMA, PredictorBank, QueryRule, one_hot_with_bias


def random_mdp(seed: int, ns: int = 5, na: int = 3, gamma: float = 0.9) -> HeightMDP:
    rng = np.random.default_rng(seed)
    p = rng.random((ns, na, ns)) ** 3
    p /= p.sum(axis=2, keepdims=True)
    r = rng.normal(size=(ns, na))
    return HeightMDP(p, r, gamma)


class OpaqueTabular:
    """The tabular basis without its type, so LSPI takes the generic LSTDQ-Model path."""

    def __init__(self, ns: int, na: int) -> None:
        self._basis = TabularBasis(ns, na)
        self.dim = self._basis.dim

    def __call__(self, states, actions):
        return self._basis(states, actions)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 100_000))
def test_lstdq_model_with_tabular_basis_is_exact_policy_evaluation(seed: int) -> None:
    mdp = random_mdp(seed)
    rng = np.random.default_rng(seed)
    policy = rng.integers(mdp.n_actions, size=mdp.n_states)
    basis = TabularBasis(mdp.n_states, mdp.n_actions)
    q_lstdq = q_from_weights(mdp, basis, lstdq_model(mdp, basis, policy))
    q_exact = evaluate_tabular(mdp, policy)
    np.testing.assert_allclose(q_lstdq, q_exact, atol=1e-8)
    # Bellman equation for the policy, independently
    v = q_exact[np.arange(mdp.n_states), policy]
    np.testing.assert_allclose(q_exact, mdp.rewards + mdp.gamma * mdp.transitions @ v, atol=1e-8)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 100_000), generic=st.booleans())
def test_lspi_finds_the_value_iteration_optimum(seed: int, generic: bool) -> None:
    mdp = random_mdp(seed, ns=int(3 + seed % 5), na=int(2 + seed % 4))
    basis = OpaqueTabular(mdp.n_states, mdp.n_actions) if generic else None
    result = lspi(mdp, basis)
    q_star = value_iteration(mdp)
    np.testing.assert_allclose(result.q.max(axis=1), q_star.max(axis=1), atol=1e-7)
    # the LSPI policy is greedy for the optimal Q
    chosen = q_star[np.arange(mdp.n_states), result.policy]
    np.testing.assert_allclose(chosen, q_star.max(axis=1), atol=1e-7)


def test_lspi_warm_start_from_the_optimal_policy_stops_at_once() -> None:
    mdp = random_mdp(7)
    first = lspi(mdp)
    again = lspi(mdp, initial_policy=first.policy)
    assert again.iterations == 1
    np.testing.assert_array_equal(again.policy, first.policy)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 100_000))
def test_full_degree_polynomial_basis_reaches_the_optimum_through_generic_lstdq(seed: int) -> None:
    # degree n_states - 1 spans every function of the state per action, so LSPI is exact again
    mdp = random_mdp(seed, ns=5, na=3)
    result = lspi(mdp, PolynomialBasis(5, 3, degree=4))
    np.testing.assert_allclose(result.q.max(axis=1), value_iteration(mdp).max(axis=1), atol=1e-6)


@settings(max_examples=50, deadline=None)
@given(margins=st.lists(st.floats(-3, 3), min_size=8 * 4, max_size=8 * 4))
def test_transition_model_follows_section_2_4(margins) -> None:
    bank = PredictorBank(range(0, 7), one_hot_with_bias(4), n_states=8)
    bank.margin[:7] = np.array(margins).reshape(8, 4)[:7]
    p = transition_model(bank, top=7)
    for s in range(7):
        for a in range(4):
            stable = (1 + np.clip(bank.margin[s, a], -1, 1)) / 2
            assert p[s, a].sum() == pytest.approx(1.0)
            assert p[s, a, s + 1] == pytest.approx(stable)
            assert np.all(p[s, a, s + 2 :] == 0)
            low = 1 if s >= 1 else 0
            np.testing.assert_allclose(p[s, a, low : s + 1], (1 - stable) / (s + 1 - low))
            if s >= 1:
                assert p[s, a, 0] == 0
    assert np.all(p[7] == 0), "the top state is absorbing with no mass"


def test_states_without_predictor_move_up_with_certainty() -> None:
    bank = PredictorBank(range(1, 4), one_hot_with_bias(3), n_states=5)
    p = transition_model(bank, top=4)
    assert np.all(p[0, :, 1] == 1.0)


def test_phantom_rewards_and_incremental_planner_match_a_fresh_build() -> None:
    rng = np.random.default_rng(11)
    bank = PredictorBank(range(1, 8), one_hot_with_bias(21), QueryRule(1.0, 0.01), n_states=9)
    for reward in ("query", "confidence"):
        planner = Planner(bank, top=8, reward=reward)
        for _ in range(300):
            bank.update(int(rng.integers(1, 8)), int(rng.integers(21)), float(rng.choice([-1, 1])))
            if rng.random() < 0.3:
                q = planner.solve()
                fresh = build_mdp(bank, 8, reward=reward)
                np.testing.assert_allclose(planner._mdp.transitions, fresh.transitions)
                np.testing.assert_allclose(planner._mdp.rewards, fresh.rewards)
                np.testing.assert_allclose(
                    q.max(axis=1), value_iteration(fresh).max(axis=1), atol=1e-7
                )
        mdp = build_mdp(bank, 8, reward=reward)
        expected = bank.unknown[1:8] if reward == "query" else bank.chi[1:8]
        np.testing.assert_array_equal(mdp.rewards[1:8], expected)
        assert np.all(mdp.rewards[[0, 8]] == 0)


def test_planner_chooses_the_most_valuable_available_height() -> None:
    bank = PredictorBank(range(1, 5), one_hot_with_bias(3), n_states=6)
    planner = Planner(bank, top=5)
    q = np.zeros((6, 3))
    q[2] = [0.1, 0.5, 0.2]
    q[3] = [0.4, 0.3, 0.0]
    q[4] = [0.9, 0.0, 0.0]
    assert planner.choose(np.array([0, 2, 3]), q) == (2, 1)
    assert planner.choose(np.array([0, 2, 3, 4]), q) == (4, 0)
    # ties between heights go to the higher one
    assert planner.choose(np.array([0, 1]), np.zeros((6, 3))) == (1, 0)


def test_invalid_planner_arguments_are_rejected() -> None:
    bank = PredictorBank(range(1, 4), one_hot_with_bias(3), n_states=5)
    with pytest.raises(ValueError, match="gamma"):
        Planner(bank, top=4, gamma=1.0)
    with pytest.raises(ValueError, match="top"):
        Planner(bank, top=5)
    with pytest.raises(ValueError, match="reward"):
        Planner(bank, top=4, reward="bogus")


def masked_value_iteration(mdp: HeightMDP, feasible: np.ndarray) -> np.ndarray:
    q = np.zeros((mdp.n_states, mdp.n_actions))
    for _ in range(100_000):
        v = np.where(feasible, q, -np.inf).max(axis=1)
        q_new = mdp.rewards + mdp.gamma * (mdp.transitions @ v)
        if np.max(np.abs(q_new - q)) < 1e-12:
            break
        q = q_new
    return np.where(feasible, q_new, -np.inf)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 100_000))
def test_lspi_with_infeasible_pairs_matches_restricted_value_iteration(seed: int) -> None:
    mdp = random_mdp(seed, ns=5, na=4)
    rng = np.random.default_rng(seed)
    feasible = rng.random((5, 4)) < 0.6
    feasible[np.arange(5), rng.integers(4, size=5)] = True  # at least one action per state
    mdp.rewards[~feasible] = 100.0  # huge rewards where nothing can happen must not attract
    result = lspi(mdp, feasible=feasible)
    assert np.all(feasible[np.arange(5), result.policy])
    expected = masked_value_iteration(mdp, feasible)
    np.testing.assert_allclose(result.q.max(axis=1), expected.max(axis=1), atol=1e-7)


def test_infeasible_unknowns_on_the_table_do_not_attract_the_plan() -> None:
    # the robot: heights 0..3 learned; on the table only action 0 can occur, so actions 1..5
    # at height 0 are never sampled and stay "unknown"; an unknown at height 2 is the real goal
    bank = PredictorBank(range(4), one_hot_with_bias(6), QueryRule(1.0, 0.1), n_states=5)
    for s in (0, 1, 2, 3):
        bank.w[bank.slot[s]] = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.95, 0.0])
        bank._refresh(s)
    bank.w[bank.slot[0]] = np.array([0.95, 0, 0, 0, 0, 0, 0.0])
    bank._refresh(0)
    bank.unknown[:] = False
    bank.unknown[0, 1:] = True  # never observable
    bank.unknown[2, 3] = True  # worth reaching
    feasible = np.ones((5, 6), dtype=bool)
    feasible[0, 1:] = False
    naive = Planner(bank, top=4)
    naive.solve()
    assert naive.choose(np.array([0, 1]))[0] == 0, "without the mask the table looks best"
    planner = Planner(bank, top=4, feasible=feasible)
    planner.solve()
    assert planner.choose(np.array([0, 1])) == (1, 5), "build towards height 2 instead"


def test_ties_within_the_tolerance_go_to_the_first_action_and_the_highest_height() -> None:
    bank = PredictorBank(range(1, 5), one_hot_with_bias(3), n_states=6)
    planner = Planner(bank, top=5)
    q = np.zeros((6, 3))
    q[2] = [0.5, 0.5 + 1e-15, 0.2]  # one rounding error apart: a tie, the first action wins
    q[3] = [0.5 - 1e-15, 0.1, 0.0]  # and height 3 ties with height 2: the higher one
    assert planner.choose(np.array([0, 2, 3]), q) == (3, 0)
    q[2, 1] = 0.5 + 1e-9  # a real difference decides
    assert planner.choose(np.array([0, 2, 3]), q) == (2, 1)


def test_variance_and_custom_phantom_rewards() -> None:
    rng = np.random.default_rng(5)
    bank = PredictorBank(range(1, 8), one_hot_with_bias(21), QueryRule(1.0, 0.01), n_states=9)
    for _ in range(200):
        bank.update(int(rng.integers(1, 8)), int(rng.integers(21)), float(rng.choice([-1, 1])))
    mdp = build_mdp(bank, 8, reward="variance")
    np.testing.assert_allclose(mdp.rewards[1:8], 1.0 - np.clip(bank.margin[1:8], -1, 1) ** 2)
    assert np.all(mdp.rewards[[0, 8]] == 0)
    table = rng.random((9, 21))
    calls = []

    def reward(rows):
        calls.append(rows.copy())
        return table[rows]

    planner = Planner(bank, top=8, reward=reward)
    q = planner.solve()
    expected = table.copy()
    expected[8] = 0.0  # the absorbing state earns nothing
    np.testing.assert_allclose(planner._mdp.rewards, expected)
    fresh = HeightMDP(build_mdp(bank, 8).transitions, expected, GAMMA)
    np.testing.assert_allclose(q.max(axis=1), value_iteration(fresh).max(axis=1), atol=1e-7)
    table[3, 4] = 50.0  # a strategy's reward changes without any model update: re-read
    planner.solve()
    assert planner._mdp.rewards[3, 4] == 50.0 and len(calls) == 2
