"""The robot run's record: ExperimentRecord, the log, replay validation and the summary."""

import dataclasses
import json
import math
import signal
import subprocess
import sys
import zipfile

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_bringup.run_report import (
    OPEN_SESSION_NAME,
    SessionClock,
    append_session,
    close_killed_session,
    read_sessions,
    write_report,
)
from katana_curiosity.core.predictors import ALPHA, THETA_ROBOT
from katana_curiosity.core.robot_loop import robot_bank
from katana_curiosity.core.run_record import (
    CheckpointError,
    CheckpointVerdict,
    ExperienceLog,
    ExperimentRecord,
    InstanceRecord,
    LogError,
    RecordError,
    check_checkpoint,
    load_checkpoint,
    read_checkpoint,
    replay,
    save_checkpoint,
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


def _log_lines(path, n: int) -> list[bytes]:
    log = ExperienceLog(path)
    for i in range(n):
        log.append(record(i, state=i % 4, action=1 + i % 6, label=1 if i % 3 else -1))
    return path.read_bytes().splitlines(keepends=True)


@settings(max_examples=40, deadline=None)
@given(n=st.integers(2, 8), data=st.data())
def test_bad_lines_are_quarantined_only_when_asked_and_nothing_is_lost(tmp_path_factory, n,
                                                                       data) -> None:
    path = tmp_path_factory.mktemp("log") / "experience.jsonl"
    lines = _log_lines(path, n)
    bad_at = sorted(data.draw(st.sets(st.integers(0, n - 1), min_size=1, max_size=n - 1)))
    damage = data.draw(st.sampled_from([b"not json\n", b'{"index": 0, "state": 1}\n',
                                        b"\xff\xfe\n"]))
    damaged = [damage if i in bad_at else line for i, line in enumerate(lines)]
    original = b"".join(damaged)
    path.write_bytes(original)
    with pytest.raises(LogError, match=f"experience.jsonl:{bad_at[0] + 1}: field"):
        ExperienceLog(path)
    assert path.read_bytes() == original, "refusing changes nothing"

    log = ExperienceLog(path, quarantine_bad_lines=True)
    kept = [json.loads(line) for i, line in enumerate(lines) if i not in bad_at]
    assert [r.index for r in log.records] == list(range(len(kept))), "contiguous again"
    for r, raw in zip(log.records, kept, strict=True):
        assert (r.state, r.action, r.label, r.wall_time) == (
            raw["state"], raw["action"], raw["label"], raw["wall_time"])
    assert [number for number, _ in log.quarantined] == [i + 1 for i in bad_at]
    assert log.quarantine_path.read_bytes() == damage * len(bad_at)
    assert log.original_path.read_bytes() == original
    assert ExperienceLog(path).records == log.records, "the new log reads without the option"


def _bank():
    return robot_bank(3, 6, ALPHA, THETA_ROBOT)


def _checkpoint_after(path, records, experiments: int) -> None:
    bank = _bank()
    replay(bank, records[:experiments])
    save_checkpoint(path, bank, experiments)


@pytest.mark.parametrize("behind", [0, 1])
def test_a_checkpoint_the_log_reproduces_is_kept(tmp_path, behind) -> None:
    records = [record(i, state=i % 4, action=1 + i % 6, label=1 if i % 3 else -1)
               for i in range(12)]
    path = tmp_path / "learner.npz"
    _checkpoint_after(path, records, 12 - behind)  # a crash between log and checkpoint: behind
    before = path.read_bytes()
    assert check_checkpoint(path, records, _bank) == CheckpointVerdict()
    assert path.read_bytes() == before


@pytest.mark.parametrize("case", ["ahead_of_the_log", "other_learner"])
def test_a_checkpoint_the_log_does_not_reproduce_is_moved_aside_unchanged(tmp_path, case) -> None:
    records = [record(i, state=i % 4, action=1 + i % 6, label=1 if i % 3 else -1)
               for i in range(30)]
    path = tmp_path / "learner.npz"
    if case == "ahead_of_the_log":  # a valid 30-experiment checkpoint beside an empty log
        _checkpoint_after(path, records, 30)
        log = []
    else:  # same length, other labels
        _checkpoint_after(path, [dataclasses.replace(r, label=-r.label) for r in records], 30)
        log = records
    before = path.read_bytes()
    verdict = check_checkpoint(path, log, _bank)
    assert not path.exists() and verdict.aside.read_bytes() == before
    assert verdict.aside.name == "learner.not-the-log-30-experiments.npz"
    assert "goes on from the log" in verdict.message and str(verdict.aside) in verdict.message
    assert load_checkpoint(verdict.aside)[1] == 30, "still a model"
    path.write_bytes(before)  # the same again: moved aside under another name
    assert check_checkpoint(path, log, _bank).aside.name == (
        "learner.not-the-log-30-experiments.2.npz")


def _not_zip(path):
    path.write_bytes(b"\x93NUMPY garbage")


def _cut_short(path):
    path.write_bytes(path.read_bytes()[:200])


def _flipped_byte(path):
    with zipfile.ZipFile(path) as archive:
        member = max(archive.infolist(), key=lambda m: m.compress_size)
    data = bytearray(path.read_bytes())
    start = member.header_offset + 30 + int.from_bytes(  # past the local header (APPNOTE 4.3.7)
        data[member.header_offset + 26:member.header_offset + 28], "little") + int.from_bytes(
        data[member.header_offset + 28:member.header_offset + 30], "little")
    data[start + member.compress_size - 1] ^= 0xFF  # its data's last byte: the CRC fails
    path.write_bytes(bytes(data))


def _no_weights(path):
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("experiments.npy", b"")


@pytest.mark.parametrize(("damage", "reason"), [
    (_not_zip, "not an .npz archive"), (_cut_short, "not an .npz archive"),
    (_flipped_byte, "damaged"), (_no_weights, "has no array")])
def test_an_unreadable_checkpoint_is_moved_aside_with_the_true_reason(tmp_path, damage,
                                                                       reason) -> None:
    records = [record(i) for i in range(5)]
    path = tmp_path / "learner.npz"
    _checkpoint_after(path, records, 5)
    damage(path)
    damaged = path.read_bytes()
    with pytest.raises(CheckpointError, match=reason):
        read_checkpoint(path)
    verdict = check_checkpoint(path, records, _bank)
    assert not path.exists() and verdict.aside.name == "learner.unreadable.npz"
    assert verdict.aside.read_bytes() == damaged
    assert reason in verdict.message and "pickled" not in verdict.message


_BEATING = """
import sys, time
from katana_bringup.run_report import SessionClock
clock = SessionClock(sys.argv[1], 5)
n = 5
while True:
    n += 1
    clock.beat(n)
    if n == 8:
        print("beat", flush=True)
    time.sleep(0.01)
"""


def test_a_killed_session_leaves_its_time_and_a_normal_one_replaces_its_open_record(
        tmp_path) -> None:
    append_session(tmp_path, {"wall_s": 2.0, "experiments_at_end": 5, "completed": False})
    proc = subprocess.Popen([sys.executable, "-c", _BEATING, str(tmp_path)],
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline() == "beat\n"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    left = json.loads((tmp_path / OPEN_SESSION_NAME).read_text())
    assert left["experiments_at_end"] >= 8 and left["wall_s"] >= 0.0
    killed = close_killed_session(tmp_path)
    assert killed == {"experiments_at_end": left["experiments_at_end"],
                      "wall_s": left["wall_s"], "completed": False, "killed": True}
    assert not (tmp_path / OPEN_SESSION_NAME).exists()
    assert close_killed_session(tmp_path) is None, "closed once"
    clock = SessionClock(tmp_path, killed["experiments_at_end"])
    clock.close({"experiments_at_end": 20, "completed": True})
    sessions = read_sessions(tmp_path)
    assert [s["experiments_at_end"] for s in sessions] == [5, left["experiments_at_end"], 20]
    assert [s.get("killed", False) for s in sessions] == [False, True, False]
    assert not (tmp_path / OPEN_SESSION_NAME).exists()
