"""The emulator's framing and CRC against docs/KATANA.md's test vectors and an independent CRC
implementation (the `crc` package's CRC-16/ARC)."""

from __future__ import annotations

import struct
import subprocess
import sys

import pytest
from crc import Calculator, Crc16
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_emulator import wire

#: docs/KATANA.md, "Link and framing": request frames and one reply, byte for byte
VECTORS = [
    (b"Z", "01 18 01 5A 3B 80"),
    (b"N\x03\x00", "01 18 03 4E 03 00 E7 60"),
    (b"D\x01", "01 18 02 44 01 C0 F2"),
    (b"C\x00\x04" + struct.pack(">h", 32000), "01 18 05 43 00 04 7D 00 5E 25"),
]
_ARC = Calculator(Crc16.IBM)  # CRC-16/ARC under the package's catalogue name


@pytest.mark.parametrize(("payload", "frame"), VECTORS)
def test_request_frames_match_the_documented_bytes(payload, frame):
    assert wire.request_frame(payload) == bytes.fromhex(frame)
    assert wire.FrameReader().feed(bytes.fromhex(frame)) == [payload]


def test_reply_and_check_value_match_the_documented_bytes():
    assert wire.with_crc(b"z") == bytes.fromhex("7A E3 81")
    assert wire.crc16(b"123456789") == 0xBB3D


@settings(deadline=None)  # no timed asserts: the machine may be loaded
@given(st.binary(max_size=300))
def test_crc_equals_an_independent_crc16_arc(data):
    assert wire.crc16(data) == _ARC.checksum(data)


def test_the_error_explanation_is_57_bytes_with_a_nul_terminated_message():
    reply = wire.error_explanation(ord("C"), -3, 2, "Axis not calibrated")
    assert len(reply) == 57
    assert reply[:4] == bytes((0xC1, ord("C"), 0xFD, 2))
    assert reply[4:55].split(b"\x00", 1)[0] == b"Axis not calibrated"
    assert reply[55:] == struct.pack(">H", _ARC.checksum(reply[:55]))


_payloads = st.lists(st.binary(min_size=1, max_size=80), max_size=6)


@settings(deadline=None)  # no timed asserts: the machine may be loaded
@given(_payloads, st.data())
def test_any_split_of_a_stream_yields_the_same_requests(payloads, data):
    """Frames and 0xC1 queries come back whole and in order however TCP cuts the stream."""
    items = [p if data.draw(st.booleans()) else None for p in payloads]
    stream = b"".join(wire.request_frame(p) if p is not None else wire.ERROR_QUERY
                      for p in items)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=8)))
    reader, got = wire.FrameReader(), []
    for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        got += reader.feed(stream[a:b])
    assert got == items and reader.bad_frames == 0


def test_garbage_and_bad_frames_are_skipped_unanswered():
    reader = wire.FrameReader()
    good = wire.request_frame(b"Z")
    bad = bytearray(wire.request_frame(b"B"))
    bad[-1] ^= 0xFF
    assert reader.feed(b"\x55\xaa" + bytes(bad) + good[:3]) == []
    assert reader.feed(good[3:] + wire.ERROR_QUERY) == [b"Z", None]
    assert reader.bad_frames == 1


@settings(deadline=None)  # no timed asserts: the machine may be loaded
@given(st.integers(1, 400), st.integers(-30000, 30000), st.integers(-30000, 30000),
       st.integers(-32768, 32767), st.integers(-32768, 32767), st.integers(-32768, 32767))
def test_a_segment_is_the_documented_polynomial(duration, target, p0, p1, p2, p3):
    """pos(t) = p0 + p1/64 t + p2/1024 t^2 + p3/32768 t^3 (docs/KATANA.md), the target from the
    segment's end on; its peak speed is the largest of the derivative sampled densely."""
    seg = wire.Segment(duration, target, p0, p1, p2, p3)
    t = duration / 3.0
    assert seg.at(t) == pytest.approx(p0 + p1 / 64 * t + p2 / 1024 * t**2 + p3 / 32768 * t**3)
    assert seg.at(duration) == target
    samples = [duration * k / 2000.0 for k in range(2001)]
    sampled = max(abs(p1 / 64 + 2 * p2 / 1024 * s + 3 * p3 / 32768 * s * s) for s in samples)
    assert sampled <= seg.peak_speed() + 1e-9
    assert seg.peak_speed() <= sampled * 1.001 + 1e-6


def test_the_emulator_loads_no_driver_module():
    """The emulator shares no code with the driver it tests (also a ruff ban): importing all of
    it, CLI included, loads no katana_driver module."""
    code = ("import sys, katana_emulator.emulator, katana_emulator.model, katana_emulator.arms; "
            "print(sorted(m for m in sys.modules if m.startswith('katana_driver')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "[]"
