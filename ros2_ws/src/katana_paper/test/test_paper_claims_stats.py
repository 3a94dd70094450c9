"""The paper's claims as statistics (katana_paper.claims): the bootstrap, the verdicts and the
seeds-to-decide estimate against independent computations, and the pages rendering
claims.json. The run folders the values come from: test_paper_claims.py."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from katana_paper import docs_report as dr
from katana_paper.claims import stats
from katana_paper.claims.core import ClaimSpec, Settings, evaluate
from katana_paper.claims.report import render_markdown
from scipy import stats as sps

FAST = Settings(resamples=2000)
GREATER = stats.Claimed("greater")


def _spec(claimed: stats.Claimed = GREATER) -> ClaimSpec:
    return ClaimSpec("c", "section 3.2, Figure 9", "words", "x minus y", claimed)


def _groups(**values) -> dict[str, dict[int, float]]:
    return {k: dict(enumerate(v)) for k, v in values.items()}


# -- the statistics --------------------------------------------------------------------------


def test_a_large_effect_passes_none_is_inconclusive_and_a_reversed_one_fails() -> None:
    rng = np.random.default_rng(1)
    base = rng.normal(0.03, 0.005, 10)
    noise = rng.normal(0.0, 0.005, 10)
    large = evaluate(_spec(), _groups(random=base + 0.05 + noise, q1=base), stats.difference,
                     FAST)
    assert large["verdict"] == "PASS" and large["ci95"][0] > 0
    assert large["seeds"] == {"random": 10, "q1": 10}
    assert large["prob_improvement"] == 1.0 and large["p_value"] < 1e-3
    none = evaluate(_spec(), _groups(random=base[::-1], q1=base), stats.difference, FAST)
    assert none["verdict"] == "INCONCLUSIVE"
    assert none["ci95"][0] < 0 < none["ci95"][1]
    reversed_ = evaluate(_spec(), _groups(random=base, q1=base + 0.05 + noise),
                         stats.difference, FAST)
    assert reversed_["verdict"] == "FAIL" and reversed_["ci95"][1] < 0
    assert reversed_["seeds_to_decide"] is None


def test_the_interval_is_a_percentile_bootstrap_of_each_group_resampled_on_its_own() -> None:
    x = np.array([0.1, 0.4, 0.35, 0.8, 0.05, 0.6])
    y = np.array([0.2, 0.25, 0.3, 0.9, 0.5])
    seen: list[tuple[np.ndarray, np.ndarray]] = []

    def recording(a, b, axis=-1):
        if a.ndim == 2:
            seen.append((a.copy(), b.copy()))
        return stats.difference(a, b, axis=axis)

    res = stats.bootstrap_result([x, y], recording, 3000, 7, 0.95)
    xs, ys = np.vstack([a for a, _ in seen]), np.vstack([b for _, b in seen])
    assert xs.shape == (3000, 6) and ys.shape == (3000, 5)
    assert np.isin(xs, x).all() and np.isin(ys, y).all()  # strata never mix
    direct = np.percentile(xs.mean(axis=1) - ys.mean(axis=1), [2.5, 97.5])
    assert (res.confidence_interval.low, res.confidence_interval.high) == pytest.approx(direct)
    est = stats.bootstrap_estimate([x, y], stats.difference, 3000, 7)
    assert est.ci == pytest.approx(tuple(direct))
    assert est.effect == pytest.approx(x.mean() - y.mean())


def test_the_interval_agrees_with_an_independent_numpy_bootstrap() -> None:
    rng = np.random.default_rng(3)
    x, y = rng.normal(1.0, 1.0, 8), rng.normal(0.2, 0.5, 12)
    est = stats.bootstrap_estimate([x, y], stats.difference, 20_000, 0)
    own = np.random.default_rng(99)
    bx = x[own.integers(0, len(x), (20_000, len(x)))].mean(axis=1)
    by = y[own.integers(0, len(y), (20_000, len(y)))].mean(axis=1)
    lo, hi = np.percentile(bx - by, [2.5, 97.5])
    width = hi - lo
    assert est.ci[0] == pytest.approx(lo, abs=0.03 * width)
    assert est.ci[1] == pytest.approx(hi, abs=0.03 * width)
    assert est.se == pytest.approx(np.std(bx - by, ddof=1), rel=0.03)


def test_a_learning_curve_band_is_a_numpy_bootstrap_of_the_mean_at_every_point() -> None:
    rng = np.random.default_rng(5)
    curves = rng.gamma(2.0, 0.2, (12, 4)) + np.linspace(1.0, 0.1, 4)  # 12 seeds, 4 points
    mean, low, high = stats.mean_band(curves, resamples=20_000)
    assert mean == pytest.approx(curves.mean(axis=0))
    own = np.random.default_rng(99)
    for point in range(4):
        column = curves[:, point]
        boot = column[own.integers(0, 12, (20_000, 12))].mean(axis=1)
        lo, hi = np.percentile(boot, [2.5, 97.5])
        assert low[point] == pytest.approx(lo, abs=0.03 * (hi - lo))
        assert high[point] == pytest.approx(hi, abs=0.03 * (hi - lo))


def test_a_band_over_few_seeds_is_their_range_and_missing_values_are_left_out() -> None:
    curves = np.array([[1.0, 2.0, np.nan], [3.0, 0.0, 5.0]])
    mean, low, high = stats.mean_band(curves)
    assert mean.tolist() == [2.0, 1.0, 5.0]
    assert low.tolist() == [1.0, 0.0, 5.0] and high.tolist() == [3.0, 2.0, 5.0]
    five = np.vstack([curves, [[2.0, 1.0, 4.0]] * 3])
    mean, low, high = stats.mean_band(five)
    assert mean[2] == pytest.approx((5.0 + 3 * 4.0) / 4)  # the seed without a value left out
    assert (low <= mean).all() and (mean <= high).all()
    assert np.isnan(stats.mean_band(np.full((3, 2), np.nan))[0]).all()


@pytest.mark.parametrize(("ci", "claimed", "expected"), [
    ((0.1, 0.2), GREATER, "PASS"), ((-0.2, -0.1), GREATER, "FAIL"),
    ((-0.1, 0.1), GREATER, "INCONCLUSIVE"), ((0.0, 0.1), GREATER, "INCONCLUSIVE"),
    ((0.1, 0.2), stats.Claimed("less", 0.3), "PASS"),
    ((0.31, 0.4), stats.Claimed("less", 0.3), "FAIL"),
    ((-0.05, 0.05), stats.Claimed("within", bounds=(-0.1, 0.1)), "PASS"),
    ((0.2, 0.3), stats.Claimed("within", bounds=(-0.1, 0.1)), "FAIL"),
    ((0.05, 0.3), stats.Claimed("within", bounds=(-0.1, 0.1)), "INCONCLUSIVE"),
    (None, GREATER, "INCONCLUSIVE"), ((math.nan, 1.0), GREATER, "INCONCLUSIVE"),
])
def test_the_verdict_rule(ci, claimed, expected) -> None:
    assert stats.verdict(ci, claimed) == expected


@given(a=st.floats(-10, 10), b=st.floats(-10, 10), null=st.floats(-10, 10))
def test_a_claim_and_its_mirror_get_mirrored_verdicts(a: float, b: float, null: float) -> None:
    lo, hi = min(a, b), max(a, b)
    up = stats.verdict((lo, hi), stats.Claimed("greater", null))
    down = stats.verdict((-hi, -lo), stats.Claimed("less", -null))
    assert up == down
    swap = {"PASS": "FAIL", "FAIL": "PASS", "INCONCLUSIVE": "INCONCLUSIVE"}
    assert stats.verdict((lo, hi), stats.Claimed("less", null)) == swap[up]


def test_the_seeds_to_decide_are_the_normal_approximation() -> None:
    est = stats.Estimate(effect=0.1, ci=(-0.05, 0.25), se=0.08, seeds=(10, 12))
    z = sps.norm.ppf(0.975) + sps.norm.ppf(0.8)
    assert stats.seeds_to_decide(est, GREATER) == math.ceil(10 * (z * 0.08 / 0.1) ** 2)
    within = stats.Claimed("within", bounds=(-0.1, 0.1))
    near = stats.Estimate(effect=0.05, ci=(-0.1, 0.2), se=0.08, seeds=(10, 10))
    assert stats.seeds_to_decide(near, within) == math.ceil(10 * (z * 0.08 / 0.05) ** 2)
    assert stats.seeds_to_decide(stats.Estimate(0.0, (-1, 1), 0.5, (5,)), GREATER) is None
    assert stats.seeds_to_decide(stats.Estimate(0.1, None, None, (1,)), GREATER) is None
    tiny = stats.Estimate(effect=1.0, ci=(-0.01, 2.0), se=0.01, seeds=(4,))
    assert stats.seeds_to_decide(tiny, GREATER) == 5  # never fewer than one more


def test_at_the_estimated_seeds_the_claim_passes_about_as_often_as_the_power() -> None:
    # Two normal groups, sd 1 and effect 0.8: the estimate from the true standard error at 6
    # seeds, then simulated experiments at that many seeds.
    sd, effect, n0 = 1.0, 0.8, 6
    est = stats.Estimate(effect, (-0.1, 1.7), math.sqrt(2 * sd**2 / n0), (n0, n0))
    n = stats.seeds_to_decide(est, GREATER)
    rng = np.random.default_rng(5)
    passed = [
        stats.verdict(stats.bootstrap_estimate(
            [rng.normal(effect, sd, n), rng.normal(0.0, sd, n)], stats.difference, 1000,
            i).ci, GREATER) == "PASS" for i in range(80)]
    assert 0.65 <= np.mean(passed) <= 0.95


def test_the_probability_of_improvement_counts_pairs() -> None:
    x, y = [0.1, 0.5, 0.5, 0.9], [0.5, 0.2, 0.7]
    pairs = sum((a > b) + 0.5 * (a == b) for a in x for b in y) / (len(x) * len(y))
    prob, p = stats.rank_test(x, y, GREATER)
    assert prob == pytest.approx(pairs)
    assert p == pytest.approx(sps.mannwhitneyu(x, y, alternative="greater").pvalue)
    prob_less, _ = stats.rank_test(x, y, stats.Claimed("less"))
    assert prob_less == pytest.approx(1 - pairs)


def test_too_few_seeds_give_no_verdict_and_missing_groups_read_not_measured() -> None:
    two = evaluate(_spec(), _groups(random=[0.5, 0.6], q1=[0.1, 0.2]), stats.difference, FAST)
    assert two["verdict"] == "INCONCLUSIVE" and two["ci95"] is None
    assert two["effect"] == pytest.approx(0.4)
    assert "fewer than 3 seeds" in two["note"]
    none = evaluate(_spec(), {"random": {}, "q1": {0: 0.1}}, stats.difference, FAST)
    assert none["effect"] is None and "not measured: no seed of random" in none["note"]
    nan = evaluate(_spec(), _groups(random=[0.5, math.nan, 0.6, 0.7], q1=[0.1, 0.2, 0.3]),
                   stats.difference, FAST)
    assert nan["seeds"] == {"random": 3, "q1": 3}
    assert list(nan["values"]["random"]) == ["0", "2", "3"]


def test_pairing_by_seed_is_reported_beside_the_stratified_verdict() -> None:
    # Seeds are worlds of very different difficulty; within a world x beats y by 0.01.
    world = np.array([0.1, 0.5, 0.2, 0.9, 0.4, 0.7])
    jitter = np.array([1, -1, 2, -2, 0, 1]) * 1e-3
    entry = evaluate(_spec(), _groups(x=world + 0.01 + jitter, y=world), stats.difference, FAST)
    assert entry["verdict"] == "INCONCLUSIVE"
    assert entry["paired"]["verdict"] == "PASS" and entry["paired"]["seeds"] == 6
    text = render_markdown({"claims": [entry], "counts": {"INCONCLUSIVE": 1}})
    assert "**INCONCLUSIVE** (paired by seed: PASS" in text
    other_seeds = {"x": {0: 1.0, 1: 2.0, 2: 3.0}, "y": {5: 1.0, 6: 2.0, 7: 3.0}}
    assert evaluate(_spec(), other_seeds, stats.difference, FAST)["paired"] is None


# -- the pages read claims.json --------------------------------------------------------------


def _doc(verdict: str = "PASS") -> dict:
    claim = evaluate(_spec(), _groups(x=[0.5, 0.6, 0.7], y=[0.1, 0.2, 0.3]), stats.difference,
                     FAST)
    claim["verdict"] = verdict
    return {"section": "3.2", "source": "runs/paper", "command":
            "katana-curiosity claims runs/paper", "method": Settings().to_json(),
            "experiments": 1000, "seeds": {"x": [0, 1, 2], "y": [0, 1, 2]},
            "counts": {"PASS": int(verdict == "PASS"), "FAIL": int(verdict == "FAIL"),
                       "INCONCLUSIVE": int(verdict == "INCONCLUSIVE")},
            "claims": [claim], "not_evaluated": []}


def test_the_pages_render_the_committed_claims_json() -> None:
    summary = {"experiments": 1000, "seeds": [0, 1, 2], "parameters": {},
               "strategies": {"q1": {"final_kl_overall": 0.03, "final_kl": {"1": 0.03}}}}
    page = dr.render_reproducing({"paper": summary, "paper-claims": _doc()})
    assert render_markdown(_doc()) in page
    assert "1. **PASS** \"words\" (section 3.2, Figure 9)." in page
    assert "1 PASS, 0 FAIL, 0 INCONCLUSIVE of 1 claims" in page
    missing = dr.render_reproducing({"paper": summary})
    assert "*Not measured*: there is no `docs/results/paper/claims.json`. Make it with " \
           "`katana-curiosity claims runs/paper`, then `python -m katana_paper.docs_report " \
           "collect paper-claims`." in missing
    other = dict(summary, seeds=[0, 1, 2, 3])
    assert "judged from other runs" in dr.paper_section(other, _doc())
    robot_summary = {"experiments": 60, "seeds": [0], "strategies": {}}
    assert "collect robot-paper-claims" in dr.robot_section(robot_summary, None)


def test_the_readme_counts_the_verdicts_only_where_claims_were_judged() -> None:
    block = dr.render_readme_block({"paper-claims": _doc("FAIL")})
    assert "| The paper's claims of section 3.2, 95 % bootstrap intervals over 3 seeds per " \
           "strategy ([REPRODUCING.md](docs/REPRODUCING.md)) | 0 PASS, 1 FAIL, 0 " \
           "INCONCLUSIVE of 1 claims | `katana-curiosity claims runs/paper` |" in block
    assert "section 3.3" not in dr.render_readme_block({})


def test_collect_copies_claims_beside_the_summary(tmp_path: Path) -> None:
    (tmp_path / "docs").mkdir()
    (tmp_path / "runs/paper").mkdir(parents=True)
    (tmp_path / "runs/paper/claims.json").write_text(json.dumps(_doc()))
    dr.collect(tmp_path, ["paper-claims"])
    copied = json.loads((tmp_path / "docs/results/paper/claims.json").read_text())
    assert copied["claims"] == _doc()["claims"]
