"""The recording format without ROS: the offered_qos_profiles text rosbag2 writes, chunked and
indexed files that the independent `rosbags` reader opens, and the repair of a file cut
anywhere (a killed writer), which keeps every message of every complete chunk."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from katana_bringup import bag_qos
from katana_bringup.recording import (
    McapRecording,
    is_indexed,
    read_recording,
    repair,
    scan_records,
)
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

STRING_DEF = "string data\n"
TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
String = TYPESTORE.types["std_msgs/msg/String"]
FILES = settings(suppress_health_check=[HealthCheck.function_scoped_fixture], deadline=None,
                 max_examples=40)
#: property tests on a shared machine: no per-example deadline (CI's profile has none)
UNTIMED = settings(deadline=None)


def cdr(text: str) -> bytes:
    """A std_msgs/String in CDR, serialized by rosbags (independent of the writer)."""
    return bytes(TYPESTORE.serialize_cdr(String(data=text), "std_msgs/msg/String"))


def read_with_rosbags(path: Path) -> dict[str, list[str]]:
    """topic -> the decoded `data` of its messages, read by rosbags from the file alone."""
    out: dict[str, list[str]] = {}
    with AnyReader([path]) as reader:
        for conn, _t, raw in reader.messages():
            out.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype).data)
    return out


# -- offered_qos_profiles ---------------------------------------------------------------------
#: what rosbag2 (Jazzy, metadata version 9) writes for a keep_last 1, reliable, volatile offer
#: with default durations: yaml-cpp's block style, no final newline
ROSBAG2_TEXT = (
    "- history: keep_last\n  depth: 1\n  reliability: reliable\n  durability: volatile\n"
    "  deadline:\n    sec: 0\n    nsec: 0\n  lifespan:\n    sec: 0\n    nsec: 0\n"
    "  liveliness: system_default\n  liveliness_lease_duration:\n    sec: 0\n    nsec: 0\n"
    "  avoid_ros_namespace_conventions: false")


def test_qos_text_is_the_one_rosbag2_writes():
    assert bag_qos.dump([bag_qos.profile(depth=1)]) == ROSBAG2_TEXT
    assert bag_qos.parse(ROSBAG2_TEXT) == [bag_qos.profile(depth=1)]
    assert bag_qos.dump([]) == "[]" and bag_qos.parse("") == [] and bag_qos.parse("[]") == []


def test_infinite_durations_are_written_as_rmw_writes_them():
    text = bag_qos.dump([bag_qos.profile(deadline_ns=bag_qos.INFINITE_NS)])
    assert "deadline:\n    sec: 9223372036\n    nsec: 854775807" in text


def test_legacy_integer_policies_are_read():
    old = yaml.safe_load(ROSBAG2_TEXT)
    old[0].update(history=1, reliability=2, durability=1, liveliness=1)
    got = bag_qos.parse(yaml.safe_dump(old))[0]
    assert (got["history"], got["reliability"], got["durability"], got["liveliness"]) == (
        "keep_last", "best_effort", "transient_local", "automatic")


profiles = st.builds(
    bag_qos.profile, history=st.sampled_from(bag_qos.HISTORY), depth=st.integers(0, 10_000),
    reliability=st.sampled_from(bag_qos.RELIABILITY),
    durability=st.sampled_from(bag_qos.DURABILITY),
    deadline_ns=st.integers(0, bag_qos.INFINITE_NS), lifespan_ns=st.integers(0, 2**62),
    liveliness=st.sampled_from(bag_qos.LIVELINESS),
    liveliness_lease_duration_ns=st.integers(0, bag_qos.INFINITE_NS),
    avoid_ros_namespace_conventions=st.booleans())


@UNTIMED
@given(st.lists(profiles, max_size=4))
def test_qos_text_round_trips_and_rosbags_reads_it(offered):
    text = bag_qos.dump(offered)
    assert bag_qos.parse(text) == offered
    from rosbags.rosbag2.metadata import parse_qos  # noqa: PLC0415 - rosbags' own parser

    read = parse_qos(text)
    assert [(q.depth, q.reliability.name.lower(), q.durability.name.lower())
            for q in read] == [(p["depth"], p["reliability"], p["durability"]) for p in offered]


@UNTIMED
@given(st.text(max_size=200) | st.recursive(
    st.none() | st.booleans() | st.integers() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(
        st.sampled_from([*bag_qos.profile(), "x"]), inner, max_size=9),
    max_leaves=20).map(yaml.safe_dump))
def test_any_text_parses_to_profiles_or_is_refused_by_name(text):
    try:
        got = bag_qos.parse(text)
    except bag_qos.QosFormatError:
        return
    assert all(set(p) == set(bag_qos.profile()) for p in got)
    assert bag_qos.parse(bag_qos.dump(got)) == got


def test_playback_offers_what_the_publishers_offered():
    latched = bag_qos.profile(history="unknown", depth=0, durability="transient_local")
    got = bag_qos.playback_profile([latched, latched])
    assert (got["history"], got["depth"], got["durability"], got["reliability"]) == (
        "keep_last", bag_qos.DEFAULT_DEPTH, "transient_local", "reliable")
    best_effort = bag_qos.profile(reliability="best_effort", history="keep_last", depth=5)
    assert bag_qos.playback_profile([best_effort])["depth"] == 5
    mixed = bag_qos.playback_profile([latched, best_effort])  # no one offer fits both
    assert mixed == bag_qos.profile()
    assert bag_qos.playback_profile([]) == bag_qos.profile()


# -- chunked, indexed files -------------------------------------------------------------------
def _record(path: Path, n: int, flush_every: int = 0) -> McapRecording:
    rec = McapRecording(path)
    rec.add_topic("/a", "std_msgs/msg/String", STRING_DEF,
                  offered_qos=[bag_qos.profile(depth=1, durability="transient_local")])
    rec.add_topic("/b", "std_msgs/msg/String", STRING_DEF)
    for i in range(n):
        rec.write("/a" if i % 3 else "/b", cdr(f"m{i}"), 1_000 + i)
        if flush_every and (i + 1) % flush_every == 0:
            rec.flush()
    return rec


def test_a_finished_recording_is_chunked_compressed_and_indexed_for_rosbags(tmp_path):
    path = tmp_path / "run.mcap"
    _record(path, 30, flush_every=7).close()
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert reader.get_header().profile == "ros2"
    assert summary.statistics.message_count == 30
    assert summary.statistics.chunk_count == 5  # 4 flushes, then finish
    assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
    assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
    assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
    with Reader(path) as bag:  # the rosbag2 reader of rosbags, on the file alone
        qos = {c.topic: c.ext.offered_qos_profiles for c in bag.connections}
        assert {c.topic: c.msgcount for c in bag.connections} == {"/a": 20, "/b": 10}
        assert {c.msgtype for c in bag.connections} == {"std_msgs/msg/String"}
    assert qos["/a"][0].durability.name == "TRANSIENT_LOCAL" and qos["/b"] == []
    got = read_with_rosbags(path)
    assert got["/b"] == [f"m{i}" for i in range(0, 30, 3)]
    assert len(got["/a"]) == 20


def test_flush_writes_the_open_chunk_and_a_kill_after_it_loses_nothing(tmp_path):
    path = tmp_path / "live.mcap"
    rec = _record(path, 10)
    assert rec.flushed == 0
    rec.flush()
    assert rec.flushed == 10
    rec.write("/a", cdr("after"), 5_000)  # in the open chunk: a kill now loses it
    killed = tmp_path / "killed.mcap"
    shutil.copy(path, killed)  # the file as SIGKILL would leave it: no summary, no footer
    rec.close()
    assert not is_indexed(killed)
    with pytest.raises(Exception, match="magic"):
        Reader(killed).open()
    assert len(list(read_recording(killed))) == 10
    report = repair(killed)
    assert report.repaired and report.messages == 10 and report.topics == {"/a": 6, "/b": 4}
    assert is_indexed(killed)
    got = read_with_rosbags(killed)
    assert got["/b"] + got["/a"] == [f"m{i}" for i in range(0, 10, 3)] + [
        f"m{i}" for i in range(10) if i % 3]
    assert repair(killed).repaired is False  # already indexed: left alone


@FILES
@given(flush_every=st.integers(1, 9), n=st.integers(1, 40), cut=st.floats(0.0, 1.0))
def test_a_file_cut_anywhere_repairs_to_every_message_of_its_complete_chunks(
        tmp_path_factory, flush_every, n, cut):
    folder = tmp_path_factory.mktemp("cut")
    path = folder / "run.mcap"
    rec = _record(path, 0)
    header_size = path.stat().st_size  # magic and header record: where a recording begins
    points = []  # (file size, messages in complete chunks) after each flush
    for i in range(n):
        rec.write("/a" if i % 3 else "/b", cdr(f"m{i}"), 1_000 + i)
        if (i + 1) % flush_every == 0:
            rec.flush()
            points.append((path.stat().st_size, i + 1))
    rec.close()
    whole = path.read_bytes()
    killed = folder / "killed.mcap"
    killed.write_bytes(whole[:int(cut * len(whole))])
    cut_at = killed.stat().st_size
    if cut_at < header_size:  # not even the header: no recording to repair
        with pytest.raises(Exception):  # noqa: B017 - any refusal, as long as it is one
            repair(killed)
        assert killed.read_bytes() == whole[:cut_at]  # the original is left as it was
        return
    at_least = max([k for size, k in points if size <= cut_at], default=0)
    at_most = min([k for size, k in points if size > cut_at], default=n)
    report = repair(killed)
    assert at_least <= report.messages <= at_most
    assert is_indexed(killed)
    got = read_with_rosbags(killed) if report.messages else {}
    assert sorted(got.get("/a", []) + got.get("/b", []), key=lambda m: int(m[1:])) == [
        f"m{i}" for i in range(report.messages)]


def test_repair_refuses_a_file_that_is_no_recording_and_leaves_it(tmp_path):
    path = tmp_path / "not.mcap"
    path.write_bytes(b"\x89MCAP0\r\nnot records at all")
    with pytest.raises(Exception):  # noqa: B017 - the refusal's kind is the library's
        repair(path)
    assert path.read_bytes() == b"\x89MCAP0\r\nnot records at all"
    assert not (tmp_path / "not.mcap.repair").exists()


def test_scan_stops_at_the_cut_and_keeps_the_channels_metadata(tmp_path):
    path = tmp_path / "run.mcap"
    _record(path, 6, flush_every=3).close()
    data = path.read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) - 40])
    channels = [r for r in scan_records(tmp_path / "cut.mcap") if hasattr(r, "topic")]
    assert {c.topic: bag_qos.parse(c.metadata["offered_qos_profiles"])[0]["durability"]
            for c in channels if c.topic == "/a"} == {"/a": "transient_local"}


def test_the_format_and_playback_logic_load_without_ros():
    code = ("import sys, katana_bringup.bag_qos, katana_bringup.recording, "
            "katana_bringup.playback; print(sorted(m for m in sys.modules "
            "if m == 'rclpy' or m.endswith('.msg')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True).stdout
    assert out.strip() == "[]"
