"""The paper's claims from run folders (katana_paper.claims): the per-seed values of both
worlds against hand-built runs, the run-folder parsing as properties, and both `claims`
commands end to end on small constructed run folders (no simulation). The statistics and the
pages: test_paper_claims_stats.py."""

from __future__ import annotations

import json
import math
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_curiosity.core.explorer import PLAN, QUERY, RANDOM
from katana_curiosity.core.run_record import ExperienceLog, ExperimentRecord
from katana_paper import robot_cli
from katana_paper.claims import abstract, robot
from katana_paper.curiosity_cli import main as curiosity_main
from katana_paper.experiments import RunConfig, RunResult, write_run_csv
from katana_paper.metrics import bernoulli_kl
from katana_paper.robot_runs import run_name as robot_runs_name
from katana_paper.robot_truth import TruthTable


def _assert_pass(doc: dict, ids: Sequence[str]) -> None:
    """Each of the claims `ids` is in claims.json and PASSes."""
    verdicts = {c["id"]: c["verdict"] for c in doc["claims"]}
    assert {i: verdicts.get(i) for i in ids} == dict.fromkeys(ids, "PASS")


# -- section 3.2: the abstract world's run folders -------------------------------------------


def _result(strategy: str, seed: int, kl: np.ndarray, states: np.ndarray, modes: np.ndarray,
            every: int) -> RunResult:
    """A RunResult holding what write_run_csv reads: KL per record, states and modes."""
    n, heights = len(states), kl.shape[1]
    record_at = np.unique(np.r_[0, np.arange(every, n + 1, every), n])
    assert len(record_at) == len(kl)
    config = RunConfig(strategy=strategy, seed=seed, experiments=n, n_blocks=heights + 1,
                       record_every=every)
    return RunResult(config, states, np.zeros(n, dtype=int), modes, np.ones(n, dtype=int),
                     record_at, kl, np.arange(1, heights + 1), np.zeros((heights + 2, 3)),
                     np.zeros(0), np.zeros((0, 1, 1)), np.zeros((0, 1, 1)),
                     np.zeros((0, 1, 1), dtype=bool))


@settings(max_examples=25, deadline=None)
@given(strategy=st.sampled_from(["q1", "q10", "conf", "random", "lp", "egreedy"]),
       seed=st.integers(0, 10_000), heights=st.integers(1, 7), every=st.integers(1, 20),
       n=st.integers(1, 120), data=st.data())
def test_a_run_csv_reads_back_what_the_writer_wrote(strategy, seed, heights, every, n, data):
    record_at = np.unique(np.r_[0, np.arange(every, n + 1, every), n])
    kl = np.array(data.draw(st.lists(st.lists(st.floats(0, 5), min_size=heights,
                                              max_size=heights),
                                     min_size=len(record_at), max_size=len(record_at))))
    states = np.array(data.draw(st.lists(st.integers(0, heights), min_size=n, max_size=n)))
    modes = np.array(data.draw(st.lists(st.sampled_from([QUERY, PLAN, RANDOM]), min_size=n,
                                        max_size=n)))
    result = _result(strategy, seed, kl, states, modes, every)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / abstract.csv_name(strategy, seed)
        write_run_csv(result, path)
        run = abstract.read_run_csv(path)
    assert (run.strategy, run.seed) == (strategy, seed)
    assert run.experiment.tolist() == record_at.tolist()
    assert run.heights == list(range(1, heights + 1))
    for i, h in enumerate(run.heights):
        np.testing.assert_allclose(run.kl[h], kl[:, i], rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose(run.kl_overall, kl.mean(axis=1), rtol=1e-5, atol=1e-12)
    for s in range(heights + 1):
        assert run.direct[s][-1] == np.sum((states == s) & (modes == QUERY))
        assert run.planned[s][-1] == np.sum((states == s) & (modes == PLAN))


@given(strategy=st.text("abcdefghijklmnopqrstuvwxyz0123456789", min_size=1, max_size=12),
       seed=st.integers(0, 10**9))
def test_run_csv_names_parse_back(strategy: str, seed: int) -> None:
    assert abstract.parse_csv_name(abstract.csv_name(strategy, seed)) == (strategy, seed)


@given(name=st.text(max_size=30))
def test_only_run_csv_names_parse(name: str) -> None:
    parsed = abstract.parse_csv_name(name)
    if parsed is not None:
        strategy, seed = parsed
        head = f"{strategy}_seed"
        assert name.startswith(head) and name.endswith(".csv")
        assert int(name[len(head):-4]) == seed


def test_bad_csvs_are_named_with_their_line(tmp_path: Path) -> None:
    path = tmp_path / "q1_seed0.csv"
    path.write_text("experiment,kl_1,kl_overall\n0,0.5,0.5\n50,x,0.4\n")
    with pytest.raises(ValueError, match=r"q1_seed0.csv:3: not a row of numbers"):
        abstract.read_run_csv(path)
    path.write_text("experiment,kl_overall\n0,0.5\n")
    with pytest.raises(ValueError, match="needs the columns"):
        abstract.read_run_csv(path)
    with pytest.raises(ValueError, match="no runs/"):
        abstract.load_folder(tmp_path)


def _abstract_run(kl: dict[int, list[float]], direct: dict[int, list[int]],
                  planned: dict[int, list[int]], every: int = 500) -> abstract.AbstractRun:
    rows = len(next(iter(kl.values())))
    return abstract.AbstractRun(
        "q1", 0, np.arange(rows) * every, {h: np.array(v, float) for h, v in kl.items()},
        np.mean([v for v in kl.values()], axis=0),
        {h: np.array(v, float) for h, v in direct.items()},
        {h: np.array(v, float) for h, v in planned.items()})


def test_the_section_32_measures_of_one_hand_built_run() -> None:
    # rows at 0, 500, 1000, 1500, 2000 experiments
    run = _abstract_run(
        kl={1: [0.4, 0.1, 0.05, 0.05, 0.04], 2: [0.4, 0.3, 0.2, 0.1, 0.04],
            3: [0.4, 0.4, 0.4, 0.3, 0.2]},
        direct={1: [0, 50, 60, 60, 60], 2: [0, 0, 30, 70, 70], 3: [0, 0, 0, 5, 20]},
        planned={0: [0, 5, 10, 15, 20], 1: [0, 0, 0, 10, 20], 2: [0, 0, 0, 0, 0],
                 3: [0, 0, 0, 0, 0]})
    # half-lives: h1 comes below 0.22 at 500, h2 below 0.22 at 1000 (0.2), h3 below 0.3 at 1500
    assert [abstract.half_life(run.kl[h], run.experiment) for h in (1, 2, 3)] == \
        [500, 1000, 1500]
    assert abstract.half_life_order(run) == pytest.approx(1.0)
    # half of the direct experience: h1 by 500, h2 by 1500 (70/2 = 35 <= 70), h3 by 2000
    assert abstract.stage_order(run) == pytest.approx(1.0)
    # h2 starts (1000) before h1 ends (1000)? no; h3 starts (1500) before h2 ends (1500)? no
    assert abstract.stage_overlap(run) == 0.0
    # direct: (60 * 1 + 70 * 2 + 20 * 3) / 150; planned: (20 * 0 + 20 * 1) / 40
    assert abstract.planned_below_direct(run) == pytest.approx(260 / 150 - 0.5)
    # heights 1-2 at 1000: 0.05 and 0.2; at the end 0.04 and 0.04
    assert abstract.early_low_kl(run) == pytest.approx(0.125)
    assert abstract.low_improvement_after_early(run) == pytest.approx(0.085)
    assert abstract.early_share_of_decrease(run) == pytest.approx(
        np.mean([0.35 / 0.36, 0.2 / 0.36]))
    assert abstract.min_final_kl(run) == pytest.approx(0.04)
    assert math.isnan(run.at(run.kl[1], 2001))


def _write_abstract_folder(folder: Path, seeds: int = 4) -> None:
    """Four strategies x `seeds` seeds of 2,000 experiments, 3 heights, written by the real
    writer: Q1 and Q10 end low, Conf in the middle, Random high except at heights 1-2."""
    rng = np.random.default_rng(0)
    every, n, heights = 100, 2000, 3
    rows = n // every + 1
    t = np.arange(rows)[:, None] / (rows - 1)
    finals = {"q1": [0.02, 0.03, 0.04], "q10": [0.021, 0.031, 0.041],
              "conf": [0.01, 0.02, 0.1], "random": [0.005, 0.01, 0.3]}
    for strategy, final in finals.items():
        for seed in range(seeds):
            f = np.array(final) * (1 + 0.05 * rng.standard_normal(heights))
            speed = np.array([20.0, 10.0, 5.0])  # lower heights learn faster
            kl = f + (0.5 - f) * np.exp(-speed * t)
            states = np.sort(rng.integers(1, heights + 1, n))  # heights in order
            modes = np.full(n, QUERY if strategy in ("q1", "q10") else RANDOM)
            if strategy in ("q1", "q10"):
                plan = rng.choice(n, n // 10, replace=False)
                modes[plan], states[plan] = PLAN, 0
            write_run_csv(_result(strategy, seed, kl, states, modes, every),
                          folder / "runs" / abstract.csv_name(strategy, seed))
    (folder / "summary.json").write_text(json.dumps({
        "experiments": n, "seeds": list(range(seeds)), "strategies": {}}))


def test_katana_curiosity_claims_end_to_end(tmp_path: Path, capsys) -> None:
    (tmp_path / "runs").mkdir()
    _write_abstract_folder(tmp_path)
    assert curiosity_main(["claims", str(tmp_path), "--resamples", "1000"]) == 0
    out = capsys.readouterr().out
    assert "section 3.2 claims" in out and f"wrote {tmp_path}/claims.json" in out
    doc = json.loads((tmp_path / "claims.json").read_text())
    _assert_pass(doc, ("q1-better-than-random", "q1-better-than-conf", "random-best-at-height-1",
                       "random-worst-at-height-3", "q1-faster-at-lower-heights",
                       "q1-stages-in-order", "q1-plans-on-lower-heights"))
    assert doc["seeds"] == {s: [0, 1, 2, 3] for s in ("conf", "q1", "q10", "random")}
    assert doc["experiments"] == 2000 and doc["section"] == "3.2"
    assert doc["command"] == f"katana-curiosity claims {tmp_path} --resamples 1000"
    assert doc["counts"] == {v: sum(c["verdict"] == v for c in doc["claims"])
                             for v in ("PASS", "FAIL", "INCONCLUSIVE")}
    for c in doc["claims"]:
        assert c["paper"] and c["measured_as"] and c["where"].startswith("section 3.2")
        assert c["verdict"] != "PASS" or c["ci95"] is not None
    md = (tmp_path / "claims.md").read_text()
    assert md.startswith("# The paper's claims, section 3.2")
    assert md.count("\n1. ") == 1 and "Figures 6-8" in md
    # the same folder judged again gives the same file: the resampling is seeded
    first = (tmp_path / "claims.json").read_text()
    assert curiosity_main(["claims", str(tmp_path), "--resamples", "1000"]) == 0
    assert (tmp_path / "claims.json").read_text() == first


def test_katana_curiosity_claims_refuses_a_folder_without_runs(tmp_path: Path, capsys) -> None:
    assert curiosity_main(["claims", str(tmp_path)]) == 2
    assert "no runs/<strategy>_seed<k>.csv" in capsys.readouterr().err


# -- section 3.3: the robot's run folders ----------------------------------------------------


def _truth() -> TruthTable:
    """Heights 0-1, three actions: on the table only a1 (always stays); at height 1 a1 always
    falls, a2 stays 5 of 10 (uncertain), a3 always stays."""
    t = TruthTable(2, 3)
    t.mark_impossible(0, 2)
    t.mark_impossible(0, 3)
    for k in range(10):
        t.record(0, 1, 1)
        t.record(1, 1, -1)
        t.record(1, 2, 1 if k < 5 else -1)
        t.record(1, 3, 1)
    return t


class Rec:
    def __init__(self, state, action, label, mode="query"):
        self.state, self.action, self.label, self.mode = state, action, label, mode

    @property
    def action_index(self) -> int:
        return self.action - 1


def test_the_per_seed_kl_is_the_hand_computed_divergence_of_the_replayed_model() -> None:
    # Ten falls of (1, a1): the RLS weights are the ridge solution w = (I + 10 x x^T)^-1 (-10 x)
    # with x = [1, 0, 0, 1] (one-hot a1 and the bias).
    truth = _truth()
    records = [Rec(1, 1, -1) for _ in range(10)]
    x = np.array([1.0, 0.0, 0.0, 1.0])
    w = np.linalg.solve(np.eye(4) + 10 * np.outer(x, x), -10 * x)
    q = [(1 + np.clip(w @ np.r_[np.eye(3)[a], 1.0], -0.99, 0.99)) / 2 for a in range(3)]
    height1 = np.mean([bernoulli_kl(0.0, q[0]), bernoulli_kl(0.5, q[1]),
                       bernoulli_kl(1.0, q[2])])
    height0 = bernoulli_kl(1.0, 0.5)  # nothing learned on the table
    got = robot.kl_after(records, truth, [5, 10, 11])
    assert got[10] == pytest.approx((height0 + height1) / 2, rel=1e-9)
    assert math.isnan(got[11]) and got[5] != got[10]
    assert robot.untrained_kl(truth) == pytest.approx(
        (math.log(2) + np.mean([math.log(2), 0.0, math.log(2)])) / 2)


def test_the_section_33_measures_of_hand_built_logs() -> None:
    truth = _truth()
    pairs = robot.uncertain_pairs(truth)
    assert pairs == {(1, 2)}
    assert robot.uncertain_pairs(truth, (0.6, 0.9)) == set()
    log = [Rec(0, 1, 1), Rec(1, 3, 1), Rec(0, 1, 1, "plan"), Rec(1, 2, 1),
           Rec(1, 2, -1), Rec(0, 1, 1, "plan"), Rec(1, 2, 1, "plan"), Rec(1, 2, 1)]
    # exploring at height 1 (the uncertain pair's; the planned a2 left out): a3, a2, a2, a2
    assert robot.share_on(log, pairs) == pytest.approx(3 / 4)
    assert robot.shift_towards(log, pairs) == pytest.approx(2 / 2 - 1 / 2)
    assert math.isnan(robot.share_on([Rec(1, 2, 1, "plan")], pairs))
    assert robot.share_on([Rec(1, 2, 1, "plan"), Rec(1, 2, 1)], pairs) == 1.0
    assert math.isnan(robot.share_on([Rec(0, 1, 1)], pairs))
    # direct: height 0 at [0] (median 0), height 1 at [1, 3, 4, 7] (median 3.5)
    assert robot.stage_order(log) == pytest.approx(1.0)
    # planned: height 0 at [2, 5] (3.5), height 1 at [6]: ((3.5 - 0) + (6 - 3.5)) / 2 / 8
    assert robot.direct_then_planned(log) == pytest.approx(((3.5 - 0) + (6 - 3.5)) / 2 / 8)
    assert math.isnan(robot.direct_then_planned([Rec(0, 1, 1)]))
    assert math.isnan(robot.stage_order([Rec(0, 1, 1, "random")]))


@given(strategy=st.text(min_size=1, max_size=20).filter(lambda s: "/" not in s),
       seed=st.integers(0, 10**9))
def test_robot_run_names_parse_back(strategy: str, seed: int) -> None:
    name = robot_runs_name(strategy, seed)
    assert name == robot.run_name(strategy, seed)
    assert robot.parse_run_name(name) == (strategy, seed)


_RECORD = st.tuples(st.integers(0, 3), st.integers(1, 6), st.sampled_from([1, -1]),
                    st.sampled_from(["query", "plan", "random"]))


@settings(max_examples=25, deadline=None)
@given(runs=st.dictionaries(st.tuples(st.sampled_from(["q1", "random", "q10"]),
                                      st.integers(0, 5)),
                            st.lists(_RECORD, max_size=12), min_size=1, max_size=4),
       stray=st.booleans())
def test_a_robot_folder_reads_back_every_run_it_holds(runs, stray) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for (strategy, seed), recs in runs.items():
            log = ExperienceLog(folder / "runs" / robot.run_name(strategy, seed) /
                                "experience.jsonl")
            for i, (s, a, label, mode) in enumerate(recs):
                log.append(ExperimentRecord(i, s, a, label, mode))
            log.path.touch()
        if stray:  # a folder that is not a run, and a run folder without a log
            (folder / "runs" / "notes").mkdir()
            (folder / "runs" / "q1-s99").mkdir()
        summary, loaded = robot.load_folder(folder)
    assert summary is None
    assert [(r.strategy, r.seed) for r in loaded] == sorted(runs)
    for r in loaded:
        assert [(x.state, x.action, x.label, x.mode) for x in r.records] == \
            list(runs[(r.strategy, r.seed)])
        assert r.theta is None


def _write_robot_folder(folder: Path, truth_path: Path, seeds: int = 3, n: int = 32) -> None:
    """q1 runs that try every pair of height 1 with the truth's outcomes; random runs that
    stay on the table but for a1 and a3 at height 1 (never the uncertain a2). A summary.json
    that names the truth."""
    outcomes = {1: [-1], 2: [1, -1], 3: [1]}
    for seed in range(seeds):
        q1 = ExperienceLog(folder / "runs" / f"q1-s{seed}" / "experience.jsonl")
        rnd = ExperienceLog(folder / "runs" / f"random-s{seed}" / "experience.jsonl")
        for i in range(n):
            if i % 4 == 0 or i < seed:
                q1.append(ExperimentRecord(i, 0, 1, 1, "query" if i < 4 else "plan"))
            else:
                a = 1 + (i + seed) % 3
                q1.append(ExperimentRecord(i, 1, a, outcomes[a][i % len(outcomes[a])],
                                           "query"))
            if i % 8 == 5:
                a = 1 + 2 * ((i // 8 + seed) % 2)
                rnd.append(ExperimentRecord(i, 1, a, outcomes[a][0], "random"))
            else:
                rnd.append(ExperimentRecord(i, 0, 1, 1, "random"))
    (folder / "summary.json").write_text(json.dumps({
        "experiments": n, "seeds": list(range(seeds)), "truth": str(truth_path),
        "strategies": {}}))


def test_katana_robot_claims_end_to_end(tmp_path: Path, capsys) -> None:
    truth_path = tmp_path / "truth.json"
    _truth().save(truth_path)
    folder = tmp_path / "robot-paper"
    _write_robot_folder(folder, truth_path)
    assert robot_cli.main(["claims", str(folder), "--resamples", "1000"]) == 0
    out = capsys.readouterr().out
    assert "section 3.3 claims" in out
    doc = json.loads((folder / "claims.json").read_text())
    _assert_pass(doc, ("q1-faster-than-random-after-15", "q1-faster-than-random-after-30",
                       "attention-on-uncertain-pairs", "robot-direct-then-planned",
                       "usable-model-after-30"))
    skipped = {s["id"] for s in doc["not_evaluated"]}
    assert {"q1-faster-than-random-after-60", "q1-faster-than-random-after-120"} <= skipped
    assert doc["uncertain_pairs"] == [[1, 2]] and doc["truth"] == str(truth_path)
    assert doc["experiments_done"] == {f"{s}-s{k}": 32 for s in ("q1", "random")
                                       for k in range(3)}
    # the per-seed KL the claims read is the replay's
    records = ExperienceLog(folder / "runs" / "q1-s1" / "experience.jsonl").records
    assert doc["kl_after"]["q1-s1"]["30"] == pytest.approx(
        robot.kl_after(records, _truth(), [30])[30], rel=1e-5)
    usable = next(c for c in doc["claims"] if c["id"] == "usable-model-after-30")
    threshold = 0.5 * robot.untrained_kl(_truth())
    assert usable["claimed"] == f"< {threshold:.3g}"
    assert (folder / "claims.md").read_text().startswith("# The paper's claims, section 3.3")


def test_katana_robot_claims_needs_a_truth_and_runs(tmp_path: Path, capsys, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)  # no docs/robot_truth.json here
    folder = tmp_path / "r"
    _write_robot_folder(folder, tmp_path / "missing.json", seeds=1, n=4)
    assert robot_cli.main(["claims", str(folder)]) == 2
    assert "no measured truth" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert robot_cli.main(["claims", str(tmp_path / "empty"), "--truth", "x.json"]) == 2
    assert "no runs/<strategy>-s<seed>" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        robot_cli.main(["claims", str(folder), "--uncertain", "0.9,0.1"])
