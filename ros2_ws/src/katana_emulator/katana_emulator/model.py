"""Katana EMULATOR motor model: six emulated motors and the controller's command semantics.

NOT a robot: a protocol-level test double (katana_emulator.emulator serves it). It follows
the facts of docs/KATANA.md and KNI 4.3.0, not the driver: each model's encoder ranges and
firmware version (katana_emulator.arms), targets within ``refuse_within`` encoders (200, the
margin a real controller is reported to keep) of a motor's stops refused with the controller's
error reply, a 300 that takes no ``H``, no flush and no all-motor calibration, speed and
acceleration limits, a spline queue, calibration (uncalibrated at boot: moves are refused with
"Axis not calibrated"), status flags and collisions.

For fault tests it counts duplicated spline segments (an H row equal to the previous one since
the last flush, other than a row that only holds every motor still: a segment sent twice),
records the largest per-10 ms joint step as a fraction of the joint's nominal top speed
(``max_speed_ratio``: above 1 the arm jumped), the largest per-tick speed change of a motor
playing splines (``max_spline_accel``, encoders per tick squared) and the calibration commands
received (``calibrations``). Knobs for what no source settles (docs/hardware.md, first
power-on checklist): the status of a moving motor (``moving_status``: 24, or KNI's 16), the
move-buffer size (``queue_size``; a full buffer reports 152), refusals answered with a ``C``
reply whose success byte is 0 instead of 0xC0 (``refuse_with_failure``), statuses forced for
tests (``status_override``). ``block_width_m``: closing fingers stall where a block that wide
holds them.

Model time is wall time times ``time_scale`` (tests and dry runs run it faster than real time).
"""

from __future__ import annotations

import math
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from katana_emulator import wire
from katana_emulator.arms import MODELS, VARIANTS, ArmModel

BANNER = "KATANA EMULATOR: a protocol-level test double, NOT a robot arm"
QUEUE_SIZE = 16  # move buffer per motor (unconfirmed; docs/KATANA.md assumes 16)
#: targets this many encoders or closer to a motor's stops are refused (docs/KATANA.md)
REFUSE_WITHIN = 200
FIRMWARE_SPEED_LIMIT = 180  # encoders per 10 ms

# Status flags (KNI's TMotStsFlg; 24 from the Katana4D manual).
OFF, CALIBRATING, HOLDING, FOLLOWING, MOVING = 0, 4, 8, 16, 24
COLLISION, SPLINE_DONE, INVALID, BUFFER_FULL = 40, 88, 128, 152
_MOVING = (FOLLOWING, MOVING, BUFFER_FULL)

# C flags; the motor id plus 128 sets the encoder counter instead.
_C_OFF, _C_CALIBRATE, _C_HOLD, _C_MOVE, _C_FLUSH = 0, 4, 8, 24, 32
_H_QUEUE = 2  # H activity: queue, do not start yet


class Refusal(Exception):
    """The emulated controller refuses a command (answered with 0xC0)."""

    def __init__(self, code: int, axis: int, message: str) -> None:
        super().__init__(message)
        self.code, self.axis, self.message = code, axis, message


@dataclass
class _Motor:
    index: int  # 1..6
    pos: float
    lo: int  # the controller's encoder range
    hi: int
    speed_limit: float  # encoders per tick
    nominal_speed: float  # the joint's top speed, encoders per tick (for the ratio)
    floor: float  # lowest position the mechanics reach (the fingers touching; lo elsewhere)
    accel_limit: float = 2.0  # encoders per tick^2
    status: int = OFF
    calibrated: bool = False
    target: float = 0.0
    vel: float = 0.0
    queue: deque = field(default_factory=deque)  # started or startable segments
    pending: list = field(default_factory=list)  # queued with G, waiting for G+128
    running: bool = False
    seg_start: float = 0.0  # tick at which queue[0] started
    run_start: float = 0.0  # tick at which the queue last started playing
    calib_end: float = 0.0
    last_row_reset: bool = False  # motion stopped since the last H row (duplicate detector)

    def stop_motion(self) -> None:
        self.last_row_reset = True
        self.queue.clear()
        self.pending.clear()
        self.running = False
        self.vel = 0.0
        self.target = self.pos


class KatanaModel:
    """Six emulated motors on the emulator's clock, and the command semantics."""

    def __init__(
        self,
        katana_type: int = 450,
        variant: str = "6M180",
        time_scale: float = 1.0,
        calibration_s: float = 4.0,
        calibrated: bool = False,
        block_width_m: float | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if time_scale <= 0.0:
            raise ValueError(f"time_scale {time_scale} must be positive")
        if katana_type not in MODELS:
            raise ValueError(f"katana_type {katana_type} not one of {sorted(MODELS)}")
        if variant not in VARIANTS:
            raise ValueError(f"variant '{variant}' not one of {', '.join(VARIANTS)}")
        self.arm: ArmModel = MODELS[katana_type]
        self.katana_type = katana_type
        self.variant = variant
        self.time_scale = time_scale
        self.calibration_s = calibration_s
        self.collision_detection = False
        #: closing fingers stop at this encoder (a held block); None: they close to touching
        self.gripper_stall_at: int | None = (
            None if block_width_m is None else self.arm.gripper.encoder_for_width(block_width_m))
        self.last_error: tuple[int, int, int, str] = (0, 0, 0, "No error")
        self.duplicated_segments = 0
        self.max_speed_ratio = 0.0  # largest per-tick step / the joint's top speed
        self.max_speed_motor = 0  # the motor (1..6) that made it
        self.max_spline_accel = 0.0  # largest per-tick speed change while playing splines
        self.calibrations = 0  # calibration commands (C flag 4) received
        self.moving_status = MOVING  # what a moving motor reports (KNI: 16 or 24)
        self.queue_size = QUEUE_SIZE
        self.refuse_within = REFUSE_WITHIN
        self.refuse_with_failure = False  # refuse C targets with success byte 0, not 0xC0
        self.status_override: dict[int, int] = {}  # motor -> status reported regardless
        #: answered to B; tests set one KNI refuses (a 400/450 above 3) to check the driver
        self.master_version: tuple[int, int] = self.arm.master_version
        self._last_row: tuple | None = None
        self._clock = clock
        self._t0 = clock()
        self._tick = 0.0
        self._lock = threading.RLock()
        self.motors: list[_Motor] = []
        for i, axis in enumerate(self.arm.axes, start=1):
            lo, hi = axis.encoder_range
            self.motors.append(_Motor(i, (lo + hi) / 2.0, lo, hi, axis.speed_enc_per_tick,
                                      axis.speed_enc_per_tick, float(lo)))
        g = self.arm.gripper
        lo, hi = g.encoder_range
        self.motors.append(_Motor(6, (lo + hi) / 2.0, lo, hi, g.speed_enc_per_tick,
                                  g.speed_enc_per_tick, float(g.touching_enc)))
        for m in self.motors:
            m.target = m.pos  # incremental encoders: an arbitrary value until calibrated
        if calibrated:
            self.finish_calibration_now()

    # ------------------------------------------------------------------ clock
    def now_tick(self) -> float:
        return (self._clock() - self._t0) * self.time_scale / wire.TICK_S

    def advance(self) -> None:
        """Bring every motor to the current model time, one 10 ms tick at a time."""
        with self._lock:
            now = math.floor(self.now_tick())
            while self._tick < now:
                if self._all_idle():
                    self._tick = now
                    break
                self._tick += 1.0
                for m in self.motors:
                    self._step(m, self._tick)

    def _all_idle(self) -> bool:
        for m in self.motors:
            if m.status == CALIBRATING or (m.running and m.queue):
                return False
            if (m.status in _MOVING or m.status == HOLDING) and (
                abs(m.target - m.pos) > 1e-9 or m.vel != 0.0
            ):
                return False
        return True

    def reset_counters(self) -> None:
        """Zero the fault-test counters (duplicated segments, largest speed ratio)."""
        with self._lock:
            self.advance()
            self.duplicated_segments = 0
            self.max_speed_ratio = 0.0
            self.max_spline_accel = 0.0

    def _step(self, m: _Motor, tick: float) -> None:
        before, was_calibrating = m.pos, m.status == CALIBRATING
        # playing on from the previous tick (not the first tick after a start: after a queue
        # that ran dry, the driver's lag, not its splines, makes that step)
        vel_before, playing = m.vel, m.running and bool(m.queue) and tick > m.run_start + 1
        self._move(m, tick)
        if m.calibrated and not was_calibrating:  # the calibration run sets, not moves, encoders
            ratio = abs(m.pos - before) / max(m.nominal_speed, 1e-9)
            if ratio > self.max_speed_ratio:
                self.max_speed_ratio, self.max_speed_motor = ratio, m.index
            if playing and m.running:  # a spline played on from the previous tick
                self.max_spline_accel = max(self.max_spline_accel, abs(m.vel - vel_before))

    def _move(self, m: _Motor, tick: float) -> None:
        if m.status in (OFF, COLLISION, INVALID):
            m.vel = 0.0
            return
        if m.status == CALIBRATING:
            if tick >= m.calib_end:
                self._calibrated(m)
            return
        if m.running and m.queue:
            prev = m.pos
            local = tick - m.seg_start
            while m.queue and local >= m.queue[0].duration:
                seg = m.queue.popleft()
                m.seg_start += seg.duration
                local = tick - m.seg_start
                m.pos = float(seg.target)
            if m.queue:
                new = m.queue[0].at(local)
                m.vel, m.pos = new - prev, new  # the step of this tick, across a segment's end too
                m.status = self._playing_status(m)
            else:
                m.running, m.vel, m.target = False, 0.0, m.pos
                m.status = SPLINE_DONE
            return
        if m.running:  # started with an empty queue
            m.running = False
        # Position control towards the target: trapezoidal speed profile.
        err = m.target - m.pos
        if abs(err) < 0.5 and abs(m.vel) <= m.accel_limit:
            m.pos, m.vel = m.target, 0.0
            if m.status in _MOVING:
                m.status = HOLDING
            return
        want = math.copysign(min(m.speed_limit, math.sqrt(2.0 * m.accel_limit * abs(err))), err)
        dv = max(-m.accel_limit, min(m.accel_limit, want - m.vel))
        m.vel += dv
        step = m.vel
        if abs(step) >= abs(err) and step * err > 0:
            step = err
        new = m.pos + step
        floor = m.floor
        if m.index == 6 and self.gripper_stall_at is not None:
            floor = max(floor, float(self.gripper_stall_at))
        if err < 0 and new <= floor:  # fingers on a block or on each other: stuck, still pushing
            new, m.vel = max(floor, min(m.pos, new)), 0.0
        m.pos = max(float(m.lo), min(float(m.hi), new))

    def _calibrated(self, m: _Motor) -> None:
        m.pos = float(self.arm.calibrated_encoders[m.index - 1])
        m.target, m.vel = m.pos, 0.0
        m.calibrated = True
        m.status = HOLDING

    def finish_calibration_now(self) -> None:
        """Skip the calibration run (tests and ``--calibrated``)."""
        with self._lock:
            for m in self.motors:
                self._calibrated(m)

    # ------------------------------------------------------------------ test hooks
    def inject_collision(self, axis: int) -> bool:
        """A collision on ``axis``: with detection on, every motor stops (status 40)."""
        with self._lock:
            self.advance()
            if not self.collision_detection:
                return False
            for m in self.motors:
                m.stop_motion()
                if m.status != OFF:
                    m.status = COLLISION
            self.last_error = (0, -10, axis, f"Collision on axis {axis}")
            return True

    def encoders(self) -> list[int]:
        with self._lock:
            self.advance()
            return [int(round(m.pos)) for m in self.motors]

    def statuses(self) -> list[int]:
        with self._lock:
            self.advance()
            return [self._reported(m) for m in self.motors]

    def _reported(self, m: _Motor) -> int:
        return self.status_override.get(m.index, m.status)

    def _playing_status(self, m: _Motor) -> int:
        """A motor playing splines: 152 with its move buffer full, else the moving status."""
        return BUFFER_FULL if len(m.queue) >= self.queue_size else self.moving_status

    # ------------------------------------------------------------------ commands
    def handle(self, payload: bytes) -> bytes:
        """Reply payload to one request payload, or b'\\xc0' when the command is refused."""
        with self._lock:
            self.advance()
            cmd = payload[0]
            try:
                expected = wire.REQUEST_LENGTHS.get(cmd)
                if expected is None:
                    raise Refusal(-1, 0, "Unknown command")
                if len(payload) != expected:
                    raise Refusal(-2, 0, f"Wrong length for this command ({len(payload)})")
                return self._dispatch(cmd, payload)
            except Refusal as r:
                self.last_error = (cmd, r.code, r.axis, r.message)
                return bytes((wire.ERROR_BYTE,))

    def error_reply(self) -> bytes:
        """The framed answer to the raw 0xC1 query: why the last command was refused."""
        with self._lock:
            return wire.error_explanation(*self.last_error)

    def _motor(self, ident: int) -> _Motor:
        if not 1 <= ident <= 6:
            raise Refusal(-4, ident, f"Invalid motor {ident}")
        return self.motors[ident - 1]

    def _dispatch(self, cmd: int, pl: bytes) -> bytes:
        if cmd == ord("Z"):
            return b"z"
        if cmd == ord("B"):
            return bytes((ord("b"), *self.master_version))
        if cmd == ord("Y"):
            text = f"{BANNER} (Katana {self.katana_type} {self.variant})".encode()
            return b"y" + text[:82].ljust(83, b"\x00")
        if cmd == ord("N"):
            if pl[1] == 3:
                return b"n" + struct.pack(">6h", *(int(round(m.pos)) for m in self.motors))
            if pl[1] == 1:
                return b"n" + bytes(self._reported(m) for m in self.motors) + bytes(6)
            raise Refusal(-1, 0, f"Unknown N sub-command {pl[1]}")
        if cmd == ord("D"):
            m = self._motor(pl[1])
            # PWM: one unsigned byte, as KNI reads it; here the duty's magnitude, 0..100 (what
            # the real byte holds is unconfirmed)
            pwm = int(min(100, round(100.0 * abs(m.vel) / max(m.speed_limit, 1.0))))
            vel = int(max(wire.INT16_MIN, min(wire.INT16_MAX, round(m.vel))))
            return b"d" + struct.pack(">BBhhB", m.index, self._reported(m),
                                      int(round(m.pos)), vel, pwm)
        if cmd == ord("C"):
            return self._motor_command(pl)
        if cmd == ord("S"):
            return self._limits(pl)
        if cmd == ord("G"):
            motor, seg = wire.read_g(pl)
            m = self._motor(motor)
            self._check_spline(m, seg, len(m.queue) + len(m.pending))
            m.pending.append(seg)
            return bytes((ord("g"), motor))
        if cmd == ord("G") + 128:
            for m in self.motors:
                if m.pending:
                    self._start_queue(m, self._tick)
                    m.queue.extend(m.pending)
                    m.pending.clear()
            return bytes((ord("g") + 128, 1))
        if cmd == ord("H"):
            if not self.arm.spline_all:
                raise Refusal(-1, 0, f"Unknown command: a Katana {self.katana_type} takes no H")
            return self._spline_all(pl)
        if cmd == ord("A"):
            self.collision_detection = bool(pl[2])
            return bytes((ord("a"), pl[2]))
        if cmd == ord("E"):
            return bytes((ord("e"), pl[1])) + bytes(16)
        raise Refusal(-1, 0, "Unknown command")

    def _spline_all(self, pl: bytes) -> bytes:
        segments, activity = wire.read_h(pl)
        for m, seg in zip(self.motors, segments, strict=True):
            self._check_spline(m, seg, len(m.queue))
        row = tuple(seg.fields() for seg in segments)
        if any(m.last_row_reset for m in self.motors):
            self._last_row = None
            for m in self.motors:
                m.last_row_reset = False
        holding = all(s.p1 == s.p2 == s.p3 == 0 and s.p0 == s.target for s in segments)
        if row == self._last_row and not holding:  # a repeated hold moves nothing
            self.duplicated_segments += 1
        self._last_row = row
        for m, seg in zip(self.motors, segments, strict=True):
            m.queue.append(seg)
            if activity != _H_QUEUE:
                self._start_queue(m, self._tick)
            if m.running:
                m.status = self._playing_status(m)
        return bytes((ord("h"), 1, activity))

    def _start_queue(self, m: _Motor, now: float) -> None:
        if not m.running:
            m.running = True
            m.seg_start = m.run_start = now
            m.status = self._playing_status(m)

    def _near_limit(self, m: _Motor, target: float) -> bool:
        """A target ``refuse_within`` encoders or closer to the ends of the motor's range."""
        return not m.lo + self.refuse_within <= target <= m.hi - self.refuse_within

    def _limit_refusal(self, m: _Motor, target: float) -> Refusal:
        return Refusal(-11, m.index, f"Target too close to the limit: {int(target)} outside "
                                     f"{m.lo + self.refuse_within}..{m.hi - self.refuse_within}")

    def _check_spline(self, m: _Motor, seg: wire.Segment, queued: int) -> None:
        if not m.calibrated:
            raise Refusal(-3, m.index, "Axis not calibrated")
        if m.status == COLLISION:
            raise Refusal(-10, m.index, "Axis stopped by a collision: hold it first")
        if queued >= self.queue_size:
            raise Refusal(-6, m.index, "Move buffer full")
        if self._near_limit(m, seg.target) and seg.target != seg.p0:
            raise self._limit_refusal(m, seg.target)
        if seg.duration <= 0:
            raise Refusal(-7, m.index, "Spline duration must be positive")
        if seg.peak_speed() > m.speed_limit * 1.05 + 1.0:
            raise Refusal(-8, m.index, "Spline faster than the speed limit")

    def _motor_command(self, pl: bytes) -> bytes:
        _, ident, flag, pos = struct.unpack(">BBBh", pl)
        set_encoder = ident >= 128
        ident &= 0x7F
        targets = self.motors if ident == 0 else [self._motor(ident)]
        if set_encoder:
            for m in targets:
                m.stop_motion()
                m.pos = m.target = float(pos)
                m.calibrated = True
            return bytes((ord("c"), 1, ident))
        if flag == _C_OFF:
            for m in targets:
                m.stop_motion()
                m.status = OFF
        elif flag == _C_CALIBRATE:
            if ident == 0 and not self.arm.calibrate_all:
                raise Refusal(-4, 0, f"A Katana {self.katana_type} calibrates motor by motor")
            self.calibrations += 1
            for m in targets:
                m.stop_motion()
                m.calibrated = False
                m.status = CALIBRATING
                m.calib_end = self._tick + self.calibration_s / wire.TICK_S
        elif flag == _C_FLUSH:
            if not self.arm.flush:
                raise Refusal(-5, ident, f"A Katana {self.katana_type} has no flush")
            for m in targets:
                m.stop_motion()
                if m.status in _MOVING or m.status == SPLINE_DONE:
                    m.status = HOLDING
        elif flag in (_C_HOLD, _C_MOVE):
            if ident == 0:
                raise Refusal(-4, 0, "Motor 0 is not valid for hold or move")
            m = targets[0]
            if flag == _C_MOVE:
                if not m.calibrated:
                    raise Refusal(-3, m.index, "Axis not calibrated")
                if m.status == COLLISION:
                    raise Refusal(-10, m.index, "Axis stopped by a collision: hold it first")
                if self._near_limit(m, pos):
                    if self.refuse_with_failure:
                        return bytes((ord("c"), 0, ident))
                    raise self._limit_refusal(m, pos)
            m.stop_motion()
            if m.calibrated:  # hold: freeze at the position sent (KNI sends where it is)
                m.target = float(pos)
            m.status = self.moving_status if flag == _C_MOVE else HOLDING
        else:
            raise Refusal(-5, ident, f"Unknown motor flag {flag}")
        return bytes((ord("c"), 1, ident))

    def _limits(self, pl: bytes) -> bytes:
        _, ident, sub, a, b, c = pl
        m = self._motor(ident)
        if sub == 3:  # speed limits, encoders per tick (positive, negative direction)
            if not 1 <= a <= FIRMWARE_SPEED_LIMIT:
                raise Refusal(-9, ident, f"Speed limit {a} outside 1..{FIRMWARE_SPEED_LIMIT}")
            m.speed_limit = float(a)
        elif sub == 4:  # acceleration limit, encoders per tick^2
            if not 1 <= a <= 4:
                raise Refusal(-9, ident, f"Acceleration limit {a} outside 1..4")
            m.accel_limit = float(a)
        return bytes((ord("s"), ident, sub, a, b, c))
