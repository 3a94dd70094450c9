"""The measured truth's statistics (katana_paper.robot_truth): hand-computed answers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from katana_paper.metrics import bernoulli_kl
from katana_paper.robot_truth import TruthTable, kl_to_truth, wilson_interval

N_ACTIONS = 6


@given(st.integers(0, 200), st.integers(0, 200))
def test_wilson_interval_contains_the_proportion_and_matches_the_formula(k, extra):
    n = k + extra
    lo, hi = wilson_interval(k, n)
    if n == 0:
        assert (lo, hi) == (0.0, 1.0)
        return
    p, z = k / n, 1.959963984540054
    # independent: the interval's ends are the roots of (p - x)^2 = z^2 x (1 - x) / n
    for x in (lo, hi):
        if 0.0 < x < 1.0:
            assert (p - x) ** 2 == pytest.approx(z * z * x * (1 - x) / n, abs=1e-9)
    assert lo <= p <= hi


def test_truth_table_json_round_trip_and_impossible_pairs():
    truth = TruthTable(4, N_ACTIONS)
    for a in range(2, 7):
        truth.mark_impossible(0, a)
    for label in (1, 1, 1, -1):
        truth.record(1, 6, label)
    truth.record(0, 1, 1)
    with pytest.raises(ValueError):
        truth.record(0, 3, 1)
    data = truth.to_json()
    assert data["p_stable"]["1"]["6"] == 0.75 and "3" not in data["p_stable"]["0"]
    assert [0, 3] in data["impossible"] and data["p_stable"]["2"]["6"] is None
    again = TruthTable.from_json(data)
    np.testing.assert_array_equal(again.possible, truth.possible)
    np.testing.assert_array_equal(again.trials, truth.trials)


def test_kl_to_truth_against_a_hand_computed_table():
    truth = TruthTable(2, 2)
    truth.mark_impossible(0, 2)
    truth.record(0, 1, 1)  # p = 1
    for label in (1, -1):
        truth.record(1, 1, label)  # p = 0.5
    for label in (1, 1, 1, -1):
        truth.record(1, 2, label)  # p = 0.75
    learned = np.array([[0.0, 0.7], [0.0, 0.0]])  # q = 0.5 everywhere measured
    kl = kl_to_truth(truth, learned)
    assert kl[0] == pytest.approx(math.log(2.0))  # KL(1 || 0.5)
    expected_h1 = (0.0 + 0.75 * math.log(1.5) + 0.25 * math.log(0.5)) / 2
    assert kl[1] == pytest.approx(expected_h1)
    assert kl[1] == pytest.approx(float(bernoulli_kl([0.5, 0.75], [0.5, 0.5]).mean()))
