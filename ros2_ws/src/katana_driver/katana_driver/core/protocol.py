"""Katana controller wire protocol: framing, CRC-16/ARC, command encoders and reply decoders.

Facts from docs/KATANA.md (gathered from the public KNI 4.3.0 sources and the ROS 1 driver;
no KNI code is copied). Layouts that no source settles are marked "unconfirmed" and kept in
one place (this module) so that a lab with the arm can correct them.

Request: ``01 18 LEN payload[LEN] CRC_hi CRC_lo``; reply: ``payload[N] CRC_hi CRC_lo`` with N
fixed per command. The CRC covers the payload only. On an error the controller answers
``C0 CRC`` instead; the client then sends the raw bytes ``00 00 00 C1`` and reads 57 bytes.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from crc import Calculator, Crc16
from katana_description import models

HEADER = 0x01
ADDRESS = 0x18  # the controller's bus address, 24
ERROR_BYTE = 0xC0
ERROR_QUERY = b"\x00\x00\x00\xc1"  # sent raw: no header, no CRC
ERROR_REPLY_LEN = 57  # C1, command, code, axis, 51-byte message, 2-byte CRC
ERROR_MESSAGE_LEN = ERROR_REPLY_LEN - 6
NUM_MOTORS = 6
ALL_MOTORS = 0

# Motor command flags of the C command.
FLAG_OFF = 0
FLAG_CALIBRATE = 4
FLAG_HOLD = 8
FLAG_MOVE = 24
FLAG_FLUSH = 32
SET_ENCODER_OFFSET = 128  # added to the motor id: set the encoder counter instead of moving

# Status flags (N 1 0, D): KNI 4.3.0's enum TMotStsFlg (include/KNI/kmlMotBase.h), whose
# comments give the new firmware's meaning: 4 calibrating, 8 holding, 16 "moving (polymb not
# full)", 40 collision, 88 "poly move finished", 152 "moving poly, polymb full", 128 not valid.
# 24 is the ROS 1 driver's "normal moving state" (Katana4D manual, quoted in its Katana.cpp)
# and the motor command flag that starts a move. Which of 16/24 a real arm reports while it
# plays splines is unconfirmed (docs/hardware.md, first power-on checklist).
STATUS_OFF = 0
STATUS_CALIBRATING = 4
STATUS_HOLDING = 8
STATUS_FOLLOWING = 16  # MSF_NORMOPSTAT: moving, the move buffer not full
STATUS_MOVING = 24
STATUS_COLLISION = 40
STATUS_SPLINE_DONE = 88
STATUS_INVALID = 128
STATUS_BUFFER_FULL = 152  # MSF_LINMOV: moving, the move buffer full (wait before sending more)
#: every status that means "this motor is moving"
MOVING_STATUSES = frozenset((STATUS_FOLLOWING, STATUS_MOVING, STATUS_BUFFER_FULL))
#: a motor at rest: holding its target, or its splines played to the end
REST_STATUSES = frozenset((STATUS_HOLDING, STATUS_SPLINE_DONE))
#: every status the driver knows (the others are logged once: docs/hardware.md's checklist)
KNOWN_STATUSES = MOVING_STATUSES | {
    STATUS_OFF, STATUS_CALIBRATING, STATUS_HOLDING, STATUS_COLLISION, STATUS_SPLINE_DONE,
    STATUS_INVALID,
}

# S sub-commands (KNI 4.3.0 src/Base/kmlMotBase.cpp): 3 speed limits, request
# ``S id 3 positive negative 0`` (CMotBase::setSpeedLimits); 4 acceleration limit, request
# ``S id 4 acceleration 0 0`` (CMotBase::setAccelerationLimit); one byte each.
SUB_SPEED_LIMIT = 3
SUB_ACCEL_LIMIT = 4
#: what the ROS 1 katana node sends to every motor at start-up (Katana::Katana() with
#: katana_constants.h: KNI_MAX_VELOCITY = 180 "velocity limit <= 180 [enc / 10 ms]",
#: KNI_MAX_ACCELERATION = 2 "acceleration limit = 1 or 2 [enc / (10 ms)^2]"); one source with
#: the arm contract and the planner: katana_description.models
KNI_MAX_VELOCITY = models.KNI_MAX_VELOCITY
KNI_MAX_ACCELERATION = models.KNI_MAX_ACCELERATION

# Activity flag of H (as the ROS 1 driver used it): more segments follow and start now,
# this is the last segment (start now), more follow and do not start yet.
ACTIVITY_START = 0
ACTIVITY_LAST = 1
ACTIVITY_QUEUE = 2

FIRMWARE_SPEED_LIMIT = 180  # encoders per 10 ms
TICK_S = models.CONTROL_TICK_S  # spline time unit: 10 ms
SPLINE_SCALE = (1, 64, 1024, 32768)  # pos(t) = p0 + p1/64 t + p2/1024 t^2 + p3/32768 t^3

INT16_MIN, INT16_MAX = -32768, 32767

# CRC-16/ARC is the catalogue name; the `crc` package calls it Crc16.IBM (check 0xBB3D).
_CRC = Calculator(Crc16.IBM, optimized=True)


class ProtocolError(Exception):
    """A frame or reply that does not follow the protocol (bad header, length or CRC)."""


class CrcError(ProtocolError):
    """The CRC of a frame does not match its payload."""


@dataclass(eq=False)
class ControllerError(Exception):
    """The controller refused a command (0xC0) and explained why on the 0xC1 request."""

    command: int  # the refused command byte
    code: int  # signed error code
    axis: int  # motor the error concerns (0: none or all)
    message: str  # the controller's own text, e.g. "Axis not calibrated"

    def __str__(self) -> str:
        letter = chr(self.command) if 32 <= self.command < 127 else f"0x{self.command:02X}"
        axis = f" on axis {self.axis}" if self.axis else ""
        return f"controller refused '{letter}'{axis}: {self.message} (code {self.code})"


class CommandFailed(ControllerError):
    """The controller answered a command normally but with its success byte 0 (KNI's
    CMotBase::sendTPS throws ParameterWritingException("TPS") on that reply to ``C``)."""

    def __str__(self) -> str:
        letter = chr(self.command) if 32 <= self.command < 127 else f"0x{self.command:02X}"
        axis = f" for motor {self.axis}" if self.axis else " for all motors"
        return f"controller answered '{letter}'{axis} with failure: {self.message}"


def crc16_arc(data: bytes) -> int:
    """CRC-16/ARC (reflected 0xA001, init 0, no final xor) of ``data``."""
    return _CRC.checksum(data)


def _crc_bytes(payload: bytes) -> bytes:
    return struct.pack(">H", crc16_arc(payload))


def frame_request(payload: bytes) -> bytes:
    """Wrap a command payload into a request frame."""
    if not 1 <= len(payload) <= 255:
        raise ValueError(f"payload length {len(payload)} outside 1..255")
    return bytes((HEADER, ADDRESS, len(payload))) + payload + _crc_bytes(payload)


def parse_request(frame: bytes) -> bytes:
    """Check a whole request frame and return its payload (the emulator's side)."""
    if len(frame) < 5 or frame[0] != HEADER or frame[1] != ADDRESS:
        raise ProtocolError(f"not a request frame: {frame.hex(' ')}")
    n = frame[2]
    if len(frame) != n + 5:
        raise ProtocolError(f"request declares {n} payload bytes but has {len(frame) - 5}")
    payload = frame[3 : 3 + n]
    if frame[3 + n :] != _crc_bytes(payload):
        raise CrcError(f"bad request CRC: {frame.hex(' ')}")
    return payload


def frame_reply(payload: bytes) -> bytes:
    """Append the CRC to a reply payload (the emulator's side)."""
    return payload + _crc_bytes(payload)


def check_reply(data: bytes, payload_len: int) -> bytes:
    """Check a reply of ``payload_len`` payload bytes plus CRC and return the payload."""
    if len(data) != payload_len + 2:
        raise ProtocolError(f"reply has {len(data)} bytes, expected {payload_len + 2}")
    payload = data[:payload_len]
    if data[payload_len:] != _crc_bytes(payload):
        raise CrcError(f"bad reply CRC: {data.hex(' ')}")
    return payload


def encode_error_reply(command: int, code: int, axis: int, message: str) -> bytes:
    """The 57-byte answer to the 0xC1 request, CRC included (the emulator's side)."""
    text = message.encode("ascii", "replace")[: ERROR_MESSAGE_LEN - 1]
    payload = struct.pack(">BBbB", 0xC1, command & 0xFF, code, axis) + text.ljust(
        ERROR_MESSAGE_LEN, b"\x00"
    )
    return frame_reply(payload)


def decode_error_reply(data: bytes) -> ControllerError:
    """Decode the 57-byte answer to the 0xC1 request."""
    payload = check_reply(data, ERROR_REPLY_LEN - 2)
    if payload[0] != 0xC1:
        raise ProtocolError(f"error reply starts with 0x{payload[0]:02X}, expected 0xC1")
    _, command, code, axis = struct.unpack(">BBbB", payload[:4])
    message = payload[4:].split(b"\x00", 1)[0].decode("ascii", "replace")
    return ControllerError(command=command, code=code, axis=axis, message=message)


def _i16(value: int) -> int:
    value = int(value)
    if not INT16_MIN <= value <= INT16_MAX:
        raise ValueError(f"{value} does not fit a signed 16-bit field")
    return value


def _u8(value: int) -> int:
    value = int(value)
    if not 0 <= value <= 255:
        raise ValueError(f"{value} does not fit a byte")
    return value


def _motor(motor: int, allow_all: bool = False) -> int:
    low = ALL_MOTORS if allow_all else 1
    if not low <= motor <= NUM_MOTORS:
        raise ValueError(f"motor id {motor} outside {low}..{NUM_MOTORS}")
    return motor


@dataclass(frozen=True)
class Command:
    """One encoded request: its payload and the length of the reply payload (CRC excluded)."""

    payload: bytes
    reply_len: int

    @property
    def letter(self) -> int:
        return self.payload[0]


@dataclass(frozen=True)
class MotorState:
    """Reply to D: one motor's status flag, position, velocity (encoders per 10 ms) and PWM."""

    status: int
    position: int
    velocity: int
    pwm: int


@dataclass(frozen=True)
class SplineSegment:
    """One motor's spline segment in firmware units: ticks of 10 ms and encoders."""

    duration: int  # ticks
    target: int  # encoder position at the end
    p0: int
    p1: int
    p2: int
    p3: int

    def coefficients(self) -> tuple[float, float, float, float]:
        """Polynomial coefficients in encoders and ticks (p_i divided by the firmware scale)."""
        p = (self.p0, self.p1, self.p2, self.p3)
        return tuple(v / s for v, s in zip(p, SPLINE_SCALE, strict=True))  # type: ignore[return-value]

    def values(self) -> tuple[int, ...]:
        return (self.duration, self.target, self.p0, self.p1, self.p2, self.p3)


# ---------------------------------------------------------------- encoders (client side)


def echo() -> Command:
    return Command(b"Z", 1)


def master_version() -> Command:
    return Command(b"B", 3)


def identification() -> Command:
    return Command(b"Y", 84)


def read_positions() -> Command:
    return Command(b"N\x03\x00", 13)


def read_status() -> Command:
    return Command(b"N\x01\x00", 13)


def read_motor(motor: int) -> Command:
    return Command(bytes((ord("D"), _motor(motor))), 8)


def motor_command(motor: int, flag: int, position: int = 0, set_encoder: bool = False) -> Command:
    """C: off (0), calibrate (4), hold (8), move (24), flush (32); motor 0 means all."""
    ident = _motor(motor, allow_all=True) + (SET_ENCODER_OFFSET if set_encoder else 0)
    return Command(struct.pack(">BBBh", ord("C"), ident, _u8(flag), _i16(position)), 3)


def calibrate_all() -> Command:
    return motor_command(ALL_MOTORS, FLAG_CALIBRATE, 32000)


def set_limit(motor: int, sub: int, a: int, b: int = 0, c: int = 0) -> Command:
    """S: sub 3 speed (a positive, b negative direction, encoders per 10 ms), sub 4 accel (a)."""
    payload = bytes((ord("S"), _motor(motor), _u8(sub), _u8(a), _u8(b), _u8(c)))
    return Command(payload, 6)


def spline_one(motor: int, segment: SplineSegment) -> Command:
    """G: one motor's segment, target before duration (queued until G+128)."""
    s = segment
    payload = struct.pack(
        ">BBhhhhhh",
        ord("G"),
        _motor(motor),
        _i16(s.target),
        _i16(s.duration),
        _i16(s.p0),
        _i16(s.p1),
        _i16(s.p2),
        _i16(s.p3),
    )
    return Command(payload, 2)


def start_splines(exact: bool = False, more: bool = False) -> Command:
    """G+128: start the segments queued with G (byte order more, exact, as KNI sends them)."""
    return Command(bytes((ord("G") + 128, int(more), int(exact))), 2)


def spline_all(segments: list[SplineSegment], activity: int, exact: bool = False) -> Command:
    """H: one segment for all six motors (per motor: duration, target, p0..p3), then flags."""
    if len(segments) != NUM_MOTORS:
        raise ValueError(f"H needs {NUM_MOTORS} segments, got {len(segments)}")
    values = [_i16(v) for s in segments for v in s.values()]
    payload = b"H" + struct.pack(">36h", *values) + bytes((_u8(activity), int(exact)))
    return Command(payload, 3)


def collision_detection(on: bool) -> Command:
    return Command(bytes((ord("A"), 0, int(on))), 2)


def gripper_sensors() -> Command:
    return Command(b"E\x0f", 18)


# ---------------------------------------------------------------- decoders (client side)


def decode_echo(payload: bytes) -> bool:
    return payload == b"z"


def decode_master_version(payload: bytes) -> tuple[int, int]:
    return payload[1], payload[2]


def decode_identification(payload: bytes) -> str:
    return payload[1:].split(b"\x00", 1)[0].decode("ascii", "replace").strip()


def decode_positions(payload: bytes) -> list[int]:
    return list(struct.unpack(">6h", payload[1:13]))


def decode_status(payload: bytes) -> list[int]:
    return list(payload[1 : 1 + NUM_MOTORS])


def decode_motor(payload: bytes) -> MotorState:
    # Layout 'd', motor, status, pos(2), vel(2), pwm as KNI reads it (CMotBase::recvPVP): pos
    # and vel signed 16-bit, pwm one unsigned byte (TMotPVP.pwm is a `byte`, unsigned char).
    status, pos, vel, pwm = struct.unpack(">BhhB", payload[2:8])
    return MotorState(status=status, position=pos, velocity=vel, pwm=pwm)


def check_motor_reply(payload: bytes | None, motor: int) -> None:
    """Raise CommandFailed when the reply to ``C`` says the command failed: its second byte
    (the success flag KNI's sendTPS/sendAPS check, ``if (!buf[1]) throw``) is 0. ``None`` (a
    reply that came but was unreadable) cannot say so and passes."""
    if payload is not None and len(payload) >= 2 and payload[1] == 0:
        raise CommandFailed(command=ord("C"), code=0, axis=motor,
                            message="success byte 0 (the controller did not take the target)")


def decode_gripper_sensors(payload: bytes) -> list[int]:
    return list(payload[2:18])


REQUEST_LENGTHS = {
    ord("Z"): 1,
    ord("B"): 1,
    ord("Y"): 1,
    ord("N"): 3,
    ord("D"): 2,
    ord("C"): 5,
    ord("S"): 6,
    ord("G"): 14,
    ord("G") + 128: 3,
    ord("H"): 75,
    ord("A"): 3,
    ord("E"): 2,
}
