"""The robot experiment's measures (robot_paper, robot_truth, contact_sheet) on constructed logs
and hand answers."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from katana_bringup.contact_sheet import contact_sheet
from katana_curiosity.core.predictors import ALPHA, THETA_ROBOT
from katana_paper import robot_paper as rp
from katana_paper.metrics import bernoulli_kl
from katana_paper.robot_truth import TrueBlock, TruthTable, placement_stayed, truth_schedule


@dataclass
class Rec:
    state: int
    action: int
    label: int
    mode: str = "query"
    wall_time: float = 0.0
    resets_before: int = 0


def _truth() -> TruthTable:
    """Height 0: action 1 always stays; height 1: action 6 stays 9/10, action 1 stays 0/10."""
    t = TruthTable(4, 6)
    for a in range(2, 7):
        t.mark_impossible(0, a)
    for _ in range(10):
        t.record(0, 1, 1)
        t.record(1, 1, -1)
    for k in range(10):
        t.record(1, 6, 1 if k else -1)
    return t


def test_the_final_kl_is_the_hand_computed_divergence_of_the_replayed_model():
    # Ten falls of (1, a1): the RLS margin of a1 at height 1 is then the ridge solution of
    # features [1,0,0,0,0,0,1] (one-hot + bias), w = A^-1 b with A = I + 10 x x^T, b = -10 x.
    records = [Rec(1, 1, -1, wall_time=10.0 + i) for i in range(10)]
    a = rp.analyse_run(records, _truth(), "q1", 0)
    x = np.zeros(7)
    x[0] = x[6] = 1.0
    w = np.linalg.solve(np.eye(7) + 10 * np.outer(x, x), -10 * x)
    q_a1 = (1 + w @ x) / 2
    x6 = np.zeros(7)
    x6[5] = x6[6] = 1.0
    q_a6 = (1 + np.clip(w @ x6, -0.99, 0.99)) / 2
    expected = np.mean([bernoulli_kl(0.0, q_a1), bernoulli_kl(0.9, q_a6)])
    assert a.kl[-1, 1] == pytest.approx(expected, rel=1e-6)
    # nothing learned at height 0: margin 0 reads as 1/2 against a truth of 1
    assert a.kl[-1, 0] == pytest.approx(math.log(2), rel=1e-6)
    assert np.isnan(a.kl[-1, 2])  # nothing measured at height 2
    assert a.s_per_experiment == pytest.approx(1.0)
    assert a.highest_stack == 0


def test_an_experiment_is_wasted_when_known_and_as_predicted_with_nothing_taught_after():
    # The first experiment at a pair is never known; once the query condition calls (1, a1)
    # known, further falls come out as predicted and teach nothing: with no experiment that
    # teaches after them (the run ends), they are wasted, as the run's summary counts them.
    records = [Rec(0, 1, 1)] + [Rec(1, 1, -1, "plan") for _ in range(30)]
    a = rp.analyse_run(records, _truth(), "q1", 0, theta=THETA_ROBOT, alpha=ALPHA)
    assert not a.known_before[0] and not a.wasted[0]
    assert not a.known_before[1]
    first_known = int(np.argmax(a.known_before[1:])) + 1
    assert a.known_before[first_known:].all()  # once known, known after more of the same
    assert a.wasted.sum() == len(records) - first_known
    assert a.wasted[first_known:].all()
    assert 1 < first_known < len(records)


@pytest.mark.parametrize("resets", [0, 1])
def test_known_experiments_leading_to_one_that_teaches_are_not_wasted_unless_a_reset_parts_them(
        resets):
    falls = [Rec(0, 1, 1)] + [Rec(1, 1, -1, "plan") for _ in range(30)]
    records = [*falls, Rec(2, 3, -1, resets_before=resets)]  # (2, a3): unknown, it teaches
    a = rp.analyse_run(records, _truth(), "q1", 0, theta=THETA_ROBOT, alpha=ALPHA)
    first_known = int(np.argmax(a.known_before[1:])) + 1
    assert not a.known_before[-1] and not a.wasted[-1]
    assert a.wasted.sum() == (len(falls) - first_known if resets else 0)


def test_summary_has_the_issue_layout(tmp_path):
    truth = _truth()
    runs = [rp.analyse_run([Rec(0, 1, 1), Rec(1, 6, 1), Rec(2, 3, -1)], truth, m, s)
            for m in ("q1", "random") for s in (0, 1)]
    summary = rp.summarise(runs, 3, [0, 1], "truth.json")
    assert set(summary) == {"experiments", "seeds", "truth", "strategies"}
    assert summary["experiments"] == 3 and summary["seeds"] == [0, 1]
    q1 = summary["strategies"]["q1"]
    assert set(q1["final_kl"]) == {"0", "1", "2", "3"}
    assert q1["final_kl"]["2"] is None  # nothing measured at height 2
    assert q1["highest_stack"] == 2  # stayed on a one-stack: two blocks
    assert q1["actions_tried"]["1"]["6"] == 2 and q1["actions_tried"]["2"]["3"] == 2
    assert q1["final_kl_overall"] == pytest.approx(np.nanmean(runs[0].kl[-1]), abs=1e-4)
    for key in ("final_kl_overall", "s_per_experiment", "wasted_share"):
        assert key in q1
    json.dumps(summary)  # serialisable
    rp.write_run_csv(runs[0], tmp_path / "run.csv")
    lines = (tmp_path / "run.csv").read_text().splitlines()
    assert len(lines) == 4 and lines[0].startswith("experiment,mode,state,action,label")


def _block(bid, x, y, level, h=0.03):
    return TrueBlock(bid, x, y, (level - 0.5) * h, level)


def test_placement_stayed_on_hand_built_scenes():
    before = [_block("red", 0.2, 0.0, 1), _block("blue", 0.2, 0.0, 2), _block("green", 0.1, 0.1, 1)]
    on_top = before[:2] + [_block("green", 0.21, 0.0, 3)]
    assert placement_stayed(before, on_top, "green", ["red", "blue"])
    fell = before[:2] + [_block("green", 0.25, 0.05, 1)]
    assert not placement_stayed(before, fell, "green", ["red", "blue"])
    toppled = [before[0], _block("blue", 0.24, 0.0, 1), _block("green", 0.2, 0.0, 2)]
    assert not placement_stayed(before, toppled, "green", ["red", "blue"])
    shoved = [before[0], _block("blue", 0.215, 0.0, 2), _block("green", 0.22, 0.0, 3)]
    assert not placement_stayed(before, shoved, "green", ["red", "blue"])
    assert placement_stayed(before, before, "green", [])  # on the table, flat
    # on the stack at the right level, but lying on its side: it fell over (as the judge says)
    on_its_side = before[:2] + [TrueBlock("green", 0.21, 0.0, 0.08, 3, flat=False)]
    assert not placement_stayed(before, on_its_side, "green", ["red", "blue"])
    on_the_table_on_its_side = before[:2] + [TrueBlock("green", 0.1, 0.1, 0.02, 1, flat=False)]
    assert not placement_stayed(before, on_the_table_on_its_side, "green", [])


@given(st.integers(1, 5), st.integers(1, 3), st.integers(2, 6))
def test_truth_schedule_balances_every_possible_pair(trials, max_height, n_actions):
    schedule = truth_schedule(trials, max_height, n_actions)
    counts = {pair: schedule.count(pair) for pair in set(schedule)}
    assert set(counts) == {(0, 1)} | {(h, a) for h in range(1, max_height + 1)
                                      for a in range(1, n_actions + 1)}
    assert set(counts.values()) == {trials}
    rounds = len(schedule) // trials
    assert sorted(schedule[:rounds]) == sorted(set(schedule))  # round by round


def test_figures_and_contact_sheet_are_written(tmp_path):
    truth = _truth()
    runs = [rp.analyse_run([Rec(0, 1, 1, "query"), Rec(1, 6, 1, "plan")] * 3, truth, "q1", s)
            for s in (0, 1)]
    rp.kl_figure(runs, tmp_path / "kl.png")
    rp.experience_figure(runs, tmp_path / "experience.png", "q1")
    rp.model_figure(runs[0], truth, tmp_path / "model.png")
    rp.truth_figure(truth, tmp_path / "truth.png")
    img = np.zeros((48, 64, 3), np.uint8)
    rows = [{"caption": f"#{i}\nh=1 a=6\nstayed", "label": 1, "images": [img, None, img, img]}
            for i in range(12)]
    contact_sheet(rows, tmp_path / "sheet.png", width_px=64)
    for name in ("kl.png", "experience.png", "model.png", "truth.png"):
        assert cv2.imread(str(tmp_path / name)) is not None
    sheet = cv2.imread(str(tmp_path / "sheet.png"))
    assert sheet.shape == (28 + 12 * 48, 150 + 4 * 64, 3)
    assert (sheet[28 + 10, 150 + 64 + 10] == 160).all()  # the missing frame is grey
