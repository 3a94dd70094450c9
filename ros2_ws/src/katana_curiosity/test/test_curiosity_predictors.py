"""The RLS bank against batch computations, and the query condition's properties."""

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from katana_curiosity.core.predictors import (
    PredictorBank,
    QueryRule,
    exploration_horizon,
    one_hot_with_bias,
)


def random_bank(seed: int, n_actions: int = 6, dim: int = 4, scale: float = 0.4):
    rng = np.random.default_rng(seed)
    features = rng.normal(0.0, scale, (n_actions, dim))
    return PredictorBank([0, 1], features, QueryRule(1.0, 0.01)), rng


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 60))
def test_rls_equals_batch_ridge_without_projection(seed: int, n: int) -> None:
    bank, rng = random_bank(seed)
    xs, ys = [], []
    for _ in range(n):
        a = int(rng.integers(bank.n_actions))
        y = float(rng.choice([-1.0, 1.0]))
        margin, _, _ = bank.evaluate(np.array([1]), bank.features[a][None])
        assume(abs(margin[0]) <= 1.0)  # only sequences on which the projection never acts
        bank.update(1, a, y)
        xs.append(bank.features[a])
        ys.append(y)
    x, y = np.array(xs), np.array(ys)
    gram = np.eye(bank.dim) + x.T @ x
    ridge = np.linalg.solve(gram, x.T @ y)
    np.testing.assert_allclose(bank.weights(1), ridge, atol=1e-9)
    np.testing.assert_allclose(bank.a_inv[bank.slot[1]], np.linalg.inv(gram), atol=1e-9)
    # the other height saw nothing
    np.testing.assert_array_equal(bank.weights(0), np.zeros(bank.dim))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 200))
def test_incremental_tables_match_direct_computation(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    bank = PredictorBank([1, 2, 3], one_hot_with_bias(5), QueryRule(0.7, 0.05), n_states=5)
    for _ in range(n):
        bank.update(int(rng.integers(1, 4)), int(rng.integers(5)), float(rng.choice([-1, 1])))
    for s in (1, 2, 3):
        k = bank.slot[s]
        quad = np.einsum("ad,de,ae->a", bank.features, bank.a_inv[k], bank.features)
        np.testing.assert_allclose(bank.quad[s], quad, atol=1e-12)
        np.testing.assert_allclose(bank.margin[s], bank.features @ bank.w[k], atol=1e-12)
        chi = 0.7 * np.sqrt(quad * math.log(1 + bank.examples[k] + 1))
        np.testing.assert_allclose(bank.chi[s], chi, atol=1e-12)
        np.testing.assert_array_equal(
            bank.unknown[s], (chi > np.abs(bank.margin[s])) & (chi > 0.05)
        )
        margins, chis, flags = bank.evaluate(np.full(5, s), bank.features)
        np.testing.assert_allclose(margins, bank.margin[s], atol=1e-12)
        np.testing.assert_allclose(chis, bank.chi[s], atol=1e-12)
    # states without a predictor stay neutral
    assert not bank.unknown[0].any() and not bank.unknown[4].any()
    assert np.all(bank.margin[0] == 0)


def test_projection_step_matches_algorithm_2_by_hand() -> None:
    features = one_hot_with_bias(3)
    bank = PredictorBank([1], features, n_states=2)
    k = bank.slot[1]
    bank.w[k] = np.array([2.0, 0.0, 0.0, 1.0])  # margin on action 0 is 3 > 1
    bank._refresh(1)
    a_inv, w, x = bank.a_inv[k].copy(), bank.w[k].copy(), features[0]
    bank.update(1, 0, -1.0)

    b = a_inv @ x
    c = x @ b
    margin = w @ x
    w_bar = w - np.sign(margin) * max(0.0, (margin - 1.0) / c) * b
    assert w_bar @ x == pytest.approx(1.0)  # projection puts the margin on x at exactly 1
    expected = w_bar + (-1.0 - w_bar @ x) / (1.0 + c) * b
    np.testing.assert_allclose(bank.weights(1), expected, atol=1e-12)
    # without the projection the update would have been different
    plain = w + (-1.0 - margin) / (1.0 + c) * b
    assert not np.allclose(plain, expected)


def test_projection_is_symmetric_for_negative_margins() -> None:
    features = one_hot_with_bias(2)
    bank = PredictorBank([1], features, n_states=2)
    k = bank.slot[1]
    bank.w[k] = np.array([-4.0, 0.0, 0.0])
    bank._refresh(1)
    b = bank.a_inv[k] @ features[0]
    c = features[0] @ b
    bank.update(1, 0, -1.0)  # after projection margin = -1 = label: only the projection acts
    w_bar = np.array([-4.0, 0.0, 0.0]) + (3.0 / c) * b
    np.testing.assert_allclose(bank.weights(1), w_bar, atol=1e-12)


def test_confidence_shrinks_with_data_at_a_feature_and_the_feature_becomes_known() -> None:
    bank = PredictorBank([1], one_hot_with_bias(4), QueryRule(1.0, 0.01), n_states=2)
    chis, flags = [], []
    for _ in range(60):
        chis.append(bank.chi[1, 2])
        flags.append(bool(bank.unknown[1, 2]))
        bank.update(1, 2, 1.0)  # a feature that is always stable
    assert all(later < earlier for earlier, later in zip(chis, chis[1:], strict=False))
    assert flags[0], "an untrained predictor must find everything unknown"
    first_known = flags.index(False)
    assert not any(flags[first_known:]), "consistent labels never make a known feature unknown"


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    theta_low=st.floats(0.0, 1.0),
    theta_high=st.floats(0.0, 1.0),
    alpha_low=st.floats(0.05, 3.0),
    alpha_high=st.floats(0.05, 3.0),
)
def test_query_condition_is_monotone_in_theta_and_alpha(
    seed, theta_low, theta_high, alpha_low, alpha_high
) -> None:
    theta_low, theta_high = sorted((theta_low, theta_high))
    alpha_low, alpha_high = sorted((alpha_low, alpha_high))
    rng = np.random.default_rng(seed)
    margin = rng.uniform(-1.5, 1.5, 50)
    c = rng.uniform(0.0, 2.0, 50)
    h = float(exploration_horizon(int(rng.integers(0, 1000))))
    strict = QueryRule(alpha_low, theta_high)
    loose = QueryRule(alpha_high, theta_low)
    tight_flags = strict.is_query(margin, strict.confidence(c, h))
    loose_flags = loose.is_query(margin, loose.confidence(c, h))
    assert np.all(loose_flags[tight_flags]), "a larger theta or smaller alpha only removes queries"


@pytest.mark.parametrize(
    ("alpha", "theta"), [(-1.0, 0.01), (0.0, 0.01), (float("nan"), 0.1), (1.0, -0.1), (1.0, 1.5)]
)
def test_invalid_query_parameters_are_rejected(alpha: float, theta: float) -> None:
    with pytest.raises(ValueError, match="alpha|theta"):
        QueryRule(alpha, theta)


def test_invalid_bank_arguments_are_rejected() -> None:
    with pytest.raises(ValueError, match="heights"):
        PredictorBank([], one_hot_with_bias(3))
    with pytest.raises(ValueError, match="heights"):
        PredictorBank([1, 1], one_hot_with_bias(3))
    with pytest.raises(ValueError, match="features"):
        PredictorBank([1], np.array([1.0, np.nan]))


def test_state_dict_round_trip_restores_the_bank() -> None:
    rng = np.random.default_rng(3)
    bank = PredictorBank([0, 1, 2, 3], one_hot_with_bias(6), QueryRule(1.0, 0.1), n_states=5)
    for _ in range(40):
        bank.update(int(rng.integers(4)), int(rng.integers(6)), float(rng.choice([-1, 1])))
    copy = PredictorBank.from_state_dict(bank.state_dict())
    for name in ("w", "a_inv", "examples", "margin", "chi", "unknown"):
        np.testing.assert_allclose(getattr(copy, name), getattr(bank, name), atol=1e-12)
    assert copy.rule == bank.rule


def test_listeners_hear_each_learned_example_with_the_margin_before_learning() -> None:
    bank = PredictorBank(range(1, 4), one_hot_with_bias(5), n_states=5)
    heard = []
    bank.listeners.append(lambda *event: heard.append(event))
    rng = np.random.default_rng(2)
    expected = []
    for _ in range(50):
        s, a, y = int(rng.integers(0, 4)), int(rng.integers(5)), float(rng.choice([-1, 1]))
        if s != 0:  # the table has no predictor: nothing is learned, nobody is told
            expected.append((s, a, y, float(bank.margin[s, a])))
        bank.update(s, a, y)
    assert heard == expected  # the margin too: both are w[a] + w[bias], bit for bit
