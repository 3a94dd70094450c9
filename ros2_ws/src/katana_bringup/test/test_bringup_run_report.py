"""The robot run's record: ExperimentRecord, the log, replay validation and the summary."""

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_bringup.run_report import append_session, read_sessions, write_report
from katana_curiosity.core.predictors import ALPHA, THETA_ROBOT
from katana_curiosity.core.robot_loop import robot_bank
from katana_curiosity.core.run_record import (
    ExperienceLog,
    ExperimentRecord,
    InstanceRecord,
    LogError,
    RecordError,
    replay,
)


def record(i: int, state: int = 1, action: int = 3, label: int = 1, **kw) -> ExperimentRecord:
    inst = InstanceRecord(320.0, 240.0, [True, False, False, False, False], [0.0] * 6 + [1.0],
                          ["b0"], [0.2, 0.1, 0.045])
    return ExperimentRecord(index=i, state=state, action=action, label=label, mode="query",
                            instance=inst, weights_before=[0.0] * 7, weights_after=[0.1] * 7,
                            stage_s={"pick_place_s": 0.5}, wall_time=100.0 + i, **kw)


def test_a_record_survives_the_log_unchanged(tmp_path) -> None:
    log = ExperienceLog(tmp_path / "experience.jsonl")
    written = [record(i, dropped_before={"grasp_missed": i}) for i in range(3)]
    for r in written:
        log.append(r)
    again = ExperienceLog(tmp_path / "experience.jsonl")
    assert again.records == written and again.moved_aside is None
    raw = json.loads((tmp_path / "experience.jsonl").read_text().splitlines()[1])
    assert raw["action_index"] == 2 and raw["dropped_before"] == {"grasp_missed": 1}
    with pytest.raises(ValueError, match="index"):
        log.append(record(7))  # not the next index


def test_replay_equals_learning_the_same_examples_directly() -> None:
    records = [record(i, state=i % 4, action=1 + i % 6, label=1 if i % 3 else -1)
               for i in range(20)]
    bank = robot_bank(3, 6, ALPHA, THETA_ROBOT)
    assert replay(bank, records) == 20
    direct = robot_bank(3, 6, ALPHA, THETA_ROBOT)
    for i in range(20):
        direct.update(i % 4, i % 6, 1.0 if i % 3 else -1.0)
    np.testing.assert_array_equal(bank.w, direct.w)


@pytest.mark.parametrize(("change", "field"), [
    ({"state": 4}, "state"), ({"action": 7}, "action")])
def test_replay_refuses_a_state_or_action_the_learner_does_not_have(change, field) -> None:
    bank = robot_bank(3, 6, ALPHA, THETA_ROBOT)
    bad = [record(0), ExperimentRecord(**{**record(1).__dict__, **change})]
    with pytest.raises(LogError, match=f"log:2: field '{field}'"):
        replay(bank, bad)
    assert int(bank.examples.sum()) == 0, "nothing learned from a log that does not replay"


_json = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=5), inner,
                                                                 max_size=3),
    max_leaves=10)


@settings(max_examples=300, deadline=None)
@given(base=st.integers(0, 2), edits=st.dictionaries(
    st.sampled_from(["index", "state", "action", "label", "mode", "setting", "available",
                     "moved_block", "attempts", "instance", "margin_before", "weights_before",
                     "stage_s", "dropped_before", "wall_time", "action_index", "other"]),
    _json, max_size=3))
def test_any_record_is_validated_or_refused_with_its_field(base, edits) -> None:
    data = json.loads(record(base).to_json())
    del data["action_index"]  # derived; checked against action only when given
    data.update(edits)
    try:
        parsed = ExperimentRecord.from_mapping(data)
    except RecordError as err:
        assert err.field_name.split(".")[0] in {*edits, "(record)"}, (err, edits)
        return
    assert parsed.label in (-1, 1) and parsed.mode in ("query", "plan", "random")
    assert parsed.index >= 0 and parsed.state >= 0 and parsed.action >= 1
    assert all(math.isfinite(v) for v in [parsed.margin_before, parsed.wall_time,
                                          *parsed.weights_before, *parsed.stage_s.values()])
    assert ExperimentRecord.from_mapping(json.loads(parsed.to_json())) == parsed


def test_a_torn_last_line_is_moved_aside_and_said(tmp_path) -> None:
    path = tmp_path / "experience.jsonl"
    log = ExperienceLog(path)
    log.append(record(0))
    good = path.read_bytes()
    path.write_bytes(good + b'{"index": 1, "sta')
    again = ExperienceLog(path)
    assert len(again) == 1 and path.read_bytes() == good
    aside, size = again.moved_aside
    assert aside.name == "experience.jsonl.corrupt" and aside.read_bytes() == b'{"index": 1, "sta'
    assert size == 17


def test_robot_report_summarises_a_log(tmp_path) -> None:
    log = ExperienceLog(tmp_path / "experience.jsonl")
    script = [
        (0, 1, 1, "query", {}),
        (1, 6, 1, "query", {"grasp_missed": 1}),
        (2, 6, -1, "query", {}),
        (1, 1, -1, "plan", {"no_block_to_move": 2, "grasp_missed": 1}),
        (2, 5, 1, "query", {}),
    ]
    for i, (state, action, label, mode, dropped) in enumerate(script):
        log.append(ExperimentRecord(index=i, state=state, action=action, label=label, mode=mode,
                                    wall_time=100.0 + 2.0 * i,
                                    stage_s={"pick_place_s": 0.5 + i}, dropped_before=dropped))
    summary = write_report(tmp_path)
    assert summary["experiments"] == 5 and summary["queries"] == 4 and summary["plans"] == 1
    assert summary["highest_stack"] == 3  # the stable placement on height 2
    assert summary["labels"]["2"] == {"6": {"stable": 0, "fell": 1}, "5": {"stable": 1, "fell": 0}}
    assert summary["s_per_experiment"] == 2.0
    assert summary["stage_median_s"]["pick_place_s"] == 2.5
    assert summary["heights_explored"] == [0, 1, 2]
    assert summary["dropped_experiments"] == {
        "total": 4, "by_reason": {"grasp_missed": 2, "no_block_to_move": 2},
        "fraction_of_attempts": round(4 / 9, 4)}
    for name in ("model.png", "experience.png"):
        assert (tmp_path / name).read_bytes()[:4] == b"\x89PNG"
        assert (tmp_path / name).stat().st_size > 10_000
    assert json.loads((tmp_path / "summary.json").read_text()) == summary


def test_sessions_are_kept_for_the_whole_run(tmp_path) -> None:
    append_session(tmp_path, {"wall_s": 3.0, "frames": ["a.png"]})
    append_session(tmp_path, {"wall_s": 4.5, "frames": []})
    assert [s["wall_s"] for s in read_sessions(tmp_path)] == [3.0, 4.5]


def test_the_summary_says_whether_the_run_kept_learning(tmp_path) -> None:
    """Queries, then a plan towards height 2 that led to a query (useful), then four identical
    known table placements ended by a setting change (wasted), then a query after the reset."""
    log = ExperienceLog(tmp_path / "experience.jsonl")
    known = {"margin_before": 0.9, "confidence_before": 0.01}
    unknown = {"margin_before": 0.0, "confidence_before": 0.8}
    script = [("query", 1, unknown, {}, 0), ("plan", 1, known, {}, 0),
              ("query", 2, unknown, {}, 0)]
    script += [("plan", 0, known, {}, 0)] * 4
    script += [("query", 1, unknown, {"plan_leads_nowhere": 1, "grasp_missed": 1}, 1)]
    for i, (mode, state, before, dropped, resets) in enumerate(script):
        log.append(ExperimentRecord(index=i, state=state, action=1, label=1, mode=mode,
                                    available=[0, 3], dropped_before=dropped,
                                    resets_before=resets, **before))
    summary = write_report(tmp_path)
    assert summary["wasted_experiments"] == {"total": 4, "fraction": 0.5,
                                             "indices": [3, 4, 5, 6]}
    assert summary["longest_identical_plan_streak"] == 4
    assert summary["last_query"] == 7
    assert summary["setting_changes_by_reason"] == {"plan_leads_nowhere": 1}
