"""The controller's side of the Katana wire protocol, written from docs/KATANA.md alone.

Shares no code with katana_driver: a driver bug in framing, CRC or a layout must show up as a
disagreement with this module, not be mirrored by it. Request ``01 18 LEN payload CRC_hi
CRC_lo``; reply ``payload CRC_hi CRC_lo``; CRC-16/ARC over the payload. A refused command is
answered ``C0 CRC``; the raw query ``00 00 00 C1`` then gets the 57-byte explanation.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

HEADER = 0x01
ADDRESS = 0x18  # bus address 24
ERROR_BYTE = 0xC0
ERROR_QUERY = b"\x00\x00\x00\xc1"  # raw: no header, no CRC
ERROR_REPLY_PAYLOAD = 55  # C1, command, code, axis, 51 message bytes (CRC excluded)
TICK_S = 0.01  # the controller's time unit: splines and limits count 10 ms ticks
INT16_MIN, INT16_MAX = -32768, 32767

#: request payload length per command byte (docs/KATANA.md, "Commands")
REQUEST_LENGTHS = {
    ord("Z"): 1, ord("B"): 1, ord("Y"): 1, ord("N"): 3, ord("D"): 2, ord("C"): 5,
    ord("S"): 6, ord("G"): 14, ord("G") + 128: 3, ord("H"): 75, ord("A"): 3, ord("E"): 2,
}


def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        table.append(crc)
    return tuple(table)


_TABLE = _crc_table()


def crc16(data: bytes) -> int:
    """CRC-16/ARC: reflected polynomial 0xA001, initial 0, no final xor ("123456789": 0xBB3D)."""
    crc = 0
    for byte in data:
        crc = (crc >> 8) ^ _TABLE[(crc ^ byte) & 0xFF]
    return crc


def with_crc(payload: bytes) -> bytes:
    """A reply: the payload and its CRC, high byte first."""
    return payload + struct.pack(">H", crc16(payload))


def request_frame(payload: bytes) -> bytes:
    """A request as a client sends it (for tests and the frame reader's own checks)."""
    return bytes((HEADER, ADDRESS, len(payload))) + with_crc(payload)


def error_explanation(command: int, code: int, axis: int, message: str) -> bytes:
    """The answer to the raw 0xC1 query, CRC included: C1, command, code (signed), axis,
    a NUL-terminated ASCII message padded to 51 bytes."""
    text = message.encode("ascii", "replace")[:50].ljust(51, b"\x00")
    return with_crc(struct.pack(">BBbB", 0xC1, command & 0xFF, code, axis) + text)


class FrameReader:
    """Splits the byte stream from a client into request payloads and raw 0xC1 queries.

    A frame with a bad CRC or address is dropped unanswered (the client times out and retries,
    as it would on the arm); stray bytes between frames are skipped."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.bad_frames = 0

    def feed(self, data: bytes) -> list[bytes | None]:
        """Complete requests in arrival order: a payload, or None for the 0xC1 query."""
        self.buf += data
        out: list[bytes | None] = []
        while self.buf:
            first = self.buf[0]
            if first == HEADER:
                if len(self.buf) < 3:
                    break
                if self.buf[1] != ADDRESS:
                    del self.buf[0]
                    continue
                n = self.buf[2]
                if len(self.buf) < n + 5:
                    break
                payload = bytes(self.buf[3 : 3 + n])
                crc = bytes(self.buf[3 + n : 5 + n])
                del self.buf[: n + 5]
                if n == 0 or crc != struct.pack(">H", crc16(payload)):
                    self.bad_frames += 1
                    continue
                out.append(payload)
            elif first == 0x00:
                if len(self.buf) < len(ERROR_QUERY):
                    if ERROR_QUERY.startswith(bytes(self.buf)):
                        break
                    del self.buf[0]
                elif bytes(self.buf[:4]) == ERROR_QUERY:
                    del self.buf[:4]
                    out.append(None)
                else:
                    del self.buf[0]
            else:
                del self.buf[0]
        return out


@dataclass(frozen=True)
class Segment:
    """One motor's spline segment as the controller stores it: duration in ticks, target and
    p0..p3 in encoders; position p0 + p1/64 t + p2/1024 t^2 + p3/32768 t^3."""

    duration: int
    target: int
    p0: int
    p1: int
    p2: int
    p3: int

    def coefficients(self) -> tuple[float, float, float, float]:
        return (float(self.p0), self.p1 / 64.0, self.p2 / 1024.0, self.p3 / 32768.0)

    def at(self, tick: float) -> float:
        """Position ``tick`` ticks into the segment; the target from its end on."""
        if tick >= self.duration:
            return float(self.target)
        c0, c1, c2, c3 = self.coefficients()
        t = max(0.0, tick)
        return c0 + t * (c1 + t * (c2 + t * c3))

    def peak_speed(self) -> float:
        """Largest |d pos / d t| over the segment, encoders per tick (a cubic's derivative is
        a parabola: its largest magnitude is at an end or at its vertex)."""
        _, c1, c2, c3 = self.coefficients()
        ts = [0.0, float(self.duration)]
        if c3 != 0.0 and 0.0 < -c2 / (3.0 * c3) < self.duration:
            ts.append(-c2 / (3.0 * c3))
        return max(abs(c1 + 2.0 * c2 * t + 3.0 * c3 * t * t) for t in ts)

    def fields(self) -> tuple[int, ...]:
        return (self.duration, self.target, self.p0, self.p1, self.p2, self.p3)


def read_g(payload: bytes) -> tuple[int, Segment]:
    """``G``: motor, target, duration, p0..p3 (target before duration)."""
    _, motor, target, duration, p0, p1, p2, p3 = struct.unpack(">BBhhhhhh", payload)
    return motor, Segment(duration, target, p0, p1, p2, p3)


def read_h(payload: bytes) -> tuple[list[Segment], int]:
    """``H``: per motor duration, target, p0..p3; then the activity byte (and the exact byte)."""
    values = struct.unpack(">36h", payload[1:73])
    return [Segment(*values[6 * i : 6 * i + 6]) for i in range(6)], payload[73]
