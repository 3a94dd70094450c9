"""katana-play without ROS: the timing of playback (each message at its recorded time scaled by
1/rate, /clock with and between the messages, loops) on a fake clock, and the command line:
every bad one refused before any work (exit 2, usage, one line naming the option)."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_bringup import bag_qos, play, playback
from katana_bringup.recording import McapRecording, is_indexed
from katana_common.cli_testing import (
    cli_settings,
    floats_outside,
    missing_files,
    names,
    refused,
    tree,
    unknown_flags,
)

CHECKS = cli_settings(25)
#: property tests on a shared machine: no per-example deadline (CI's profile has none)
UNTIMED = settings(deadline=None)


class FakeClock:
    """Wall time that only moves when playback waits; records what was published when."""

    def __init__(self, stop_after: int | None = None) -> None:
        self.t = 100.0
        self.events: list[tuple[str, float, object]] = []
        self.stop_after = stop_after

    def now(self) -> float:
        return self.t

    def wait_until(self, t: float) -> bool:
        self.t = max(self.t, t)
        published = sum(1 for kind, _, _ in self.events if kind == "msg")
        return self.stop_after is None or published < self.stop_after

    def publish(self, msg: playback.Recorded) -> None:
        self.events.append(("msg", self.t, msg))

    def publish_clock(self, ns: int) -> None:
        self.events.append(("clock", self.t, ns))


def _messages(gaps_ns: list[int]) -> list[playback.Recorded]:
    t, out = 5_000_000_000, []
    for i, gap in enumerate(gaps_ns):
        t += gap
        out.append(playback.Recorded("/a" if i % 2 else "/b", t, bytes([i % 256])))
    return out


@UNTIMED
@given(gaps=st.lists(st.integers(0, 3_000_000_000), min_size=1, max_size=30),
       rate=st.floats(0.05, 20.0), delay=st.floats(0.0, 2.0))
def test_each_message_at_its_recorded_time_over_rate_with_the_clock(gaps, rate, delay):
    msgs = _messages(gaps)
    clock = FakeClock()
    n = playback.play(lambda: msgs, rate, False, clock.publish, clock.publish_clock,
                      clock.now, clock.wait_until, delay_s=delay)
    assert n == len(msgs)
    sent = [(t, m) for kind, t, m in clock.events if kind == "msg"]
    assert [m for _, m in sent] == msgs
    start = sent[0][0]
    assert start == pytest.approx(100.0 + delay)
    for t, m in sent:
        assert t == pytest.approx(start + (m.log_time_ns - msgs[0].log_time_ns) / 1e9 / rate,
                                  abs=1e-6)
    ticks = [(t, ns) for kind, t, ns in clock.events if kind == "clock"]
    assert [ns for _, ns in ticks] == sorted(ns for _, ns in ticks)  # time never goes back
    for i, (kind, _t, m) in enumerate(clock.events):
        if kind == "msg":  # the clock reads the message's own time when it goes out
            assert clock.events[i - 1][0] == "clock" and clock.events[i - 1][2] == m.log_time_ns
    walls = [t for t, _ in ticks]
    assert all(b - a <= 1.0 / playback.CLOCK_HZ + 1e-9 for a, b in zip(walls, walls[1:],
                                                                          strict=False))


def test_loop_plays_again_from_the_start_until_stopped():
    msgs = _messages([0, 1_000_000, 2_000_000])
    clock = FakeClock(stop_after=8)
    n = playback.play(lambda: msgs, 1.0, True, clock.publish, clock.publish_clock,
                      clock.now, clock.wait_until)
    sent = [m for kind, _, m in clock.events if kind == "msg"]
    assert n == 8 and sent == (msgs * 3)[:8]


def test_an_empty_recording_plays_nothing_even_in_a_loop():
    clock = FakeClock()
    assert playback.play(lambda: [], 1.0, True, clock.publish, clock.publish_clock,
                         clock.now, clock.wait_until) == 0


# -- the command line -------------------------------------------------------------------------
def _recording(folder: Path, finished: bool = True) -> Path:
    path = folder / "run.mcap"
    rec = McapRecording(path)
    rec.add_topic("/memory/blocks", "std_msgs/msg/String", "string data\n",
                  offered_qos=[bag_qos.profile(durability="transient_local", depth=1)])
    rec.write("/memory/blocks", b"\x00\x01\x00\x00\x01\x00\x00\x00\x00\x00\x00\x00", 1)
    rec.flush()
    if finished:
        rec.close()
    return path


def test_good_command_lines_are_taken(tmp_path):
    path = _recording(tmp_path)
    args = playback.parse_args([str(path), "--rate", "2.5", "--loop", "--topics",
                                "memory/blocks", "--delay", "1"])
    assert (args.rate, args.loop, args.topics, args.delay) == (2.5, True, ["/memory/blocks"],
                                                               1.0)
    assert playback.parse_args([str(path)]).topics is None


PLAY_OPTIONS = {
    "--rate": floats_outside(0.0, low_open=True),
    "--delay": floats_outside(0.0),
    "--topics": names.filter(lambda n: n != "memory") | st.sampled_from(["", "/", "a b"]),
}


@CHECKS
@given(data=st.data(), option=st.sampled_from(sorted(PLAY_OPTIONS)))
def test_a_bad_value_of_each_option_is_refused_naming_it(tmp_path, capsys, data, option):
    path = _recording(tmp_path)
    before = tree(tmp_path)
    value = data.draw(PLAY_OPTIONS[option])
    line = refused(play.main, [str(path), f"{option}={value}"], capsys)
    assert option in line, line
    assert tree(tmp_path) == before


@CHECKS
@given(name=missing_files)
def test_a_missing_file_is_refused(tmp_path, capsys, name):
    refused(play.main, [str(tmp_path / name)], capsys)


def test_a_file_that_is_no_recording_is_refused(tmp_path, capsys):
    (tmp_path / "notes.mcap").write_text("hello")
    assert "not an MCAP file" in refused(play.main, [str(tmp_path / "notes.mcap")], capsys)


@CHECKS
@given(option=st.sampled_from([["--rate", "2"], ["--loop"], ["--topics", "/memory/blocks"],
                               ["--delay", "1"]]))
def test_repair_takes_no_playback_option(tmp_path, capsys, option):
    path = _recording(tmp_path, finished=False)
    line = refused(play.main, [str(path), "--repair", *option], capsys)
    assert option[0] in line and "--repair" in line
    assert not is_indexed(path)  # refused before any work


@CHECKS
@given(data=st.data())
def test_unknown_options_are_refused(tmp_path, capsys, data):
    path = _recording(tmp_path)
    flag = data.draw(unknown_flags(playback.build_parser()))
    refused(play.main, [str(path), flag], capsys)


def test_repair_command_indexes_a_killed_recorders_file(tmp_path, capsys):
    path = _recording(tmp_path, finished=False)
    assert play.main([str(path), "--repair"]) == 0
    assert is_indexed(path) and "rewrote it indexed with its 1 complete messages" in \
        capsys.readouterr().out
    assert play.main([str(path), "--repair"]) == 0
    assert "already indexed" in capsys.readouterr().out
    assert playback.recorded_topics(path)["/memory/blocks"].count == 1
