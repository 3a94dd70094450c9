"""Katana EMULATOR motor model: six emulated motors and the controller's command semantics.

NOT a robot: a protocol-level test double (see katana_driver.emulator for the server). Speed
and acceleration limits, a spline queue, calibration state (uncalibrated at boot: moves are
refused with "Axis not calibrated"), status flags and collision injection. For fault tests it
counts duplicated spline segments (an H row equal to the previous one since the last flush,
other than a row that only holds every motor still: a segment the driver sent twice) and
records the largest per-10 ms joint step as a fraction of the joint's speed limit
(``max_speed_ratio``: above 1 the arm jumped), the largest per-tick speed change of a motor
playing splines (``max_spline_accel``, encoders per tick squared) and the calibration commands
received (``calibrations``).

Knobs for what no source settles (docs/hardware.md, first power-on checklist): the status of a
moving motor (``moving_status``: 24, or KNI's 16), the move-buffer size (``queue_size``; a full
buffer reports 152), targets refused near the limits (``refuse_within`` encoders, answered with
0xC0 or, with ``refuse_with_failure``, with a ``C`` reply whose success byte is 0) and statuses
forced for tests (``status_override``).

Model time is wall time times ``time_scale`` (tests run it faster than real time).
"""

from __future__ import annotations

import math
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from katana_driver.core import protocol as p
from katana_driver.core.encoders import EncoderModel
from katana_driver.core.splines import cubic_speed_max, evaluate

BANNER = "KATANA EMULATOR: a protocol-level test double, NOT a robot arm"
QUEUE_SIZE = 16  # move buffer per motor (the real size is unconfirmed; docs/KATANA.md assumes 16)
#: the master version answered to B: KNI accepts a 400/450 only up to 3 and a 300 only from 3
#: (kmlBase.h K400_OLD_PROTOCOL_THRESHOLD = 3); what a real controller answers is unconfirmed
MASTER_VERSION = (3, 0)
ENCODER_OFFSETS = (31000, -31000, -31000, 31000, 31000, 31000)


class Refusal(Exception):
    """The emulated controller refuses a command (answered with 0xC0)."""

    def __init__(self, code: int, axis: int, message: str) -> None:
        super().__init__(message)
        self.code, self.axis, self.message = code, axis, message


@dataclass
class _Motor:
    index: int  # 1..6
    pos: float
    lo: int
    hi: int
    speed_limit: float  # encoders per tick
    nominal_speed: float = 0.0  # the joint's speed limit, encoders per tick (for the ratio)
    accel_limit: float = 2.0  # encoders per tick^2 (the firmware's unit is unconfirmed)
    status: int = p.STATUS_OFF
    calibrated: bool = False
    target: float = 0.0
    vel: float = 0.0
    queue: deque = field(default_factory=deque)  # started or startable SplineSegments
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
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if time_scale <= 0.0:
            raise ValueError("time_scale must be positive")
        self.katana_type = katana_type
        self.variant = variant
        self.time_scale = time_scale
        self.calibration_s = calibration_s
        self.collision_detection = False
        self.gripper_stall_at: int | None = None  # closing fingers stop here (a held block)
        self.last_error: tuple[int, int, int, str] = (0, 0, 0, "No error")
        self.duplicated_segments = 0
        self.max_speed_ratio = 0.0  # largest per-tick step / the joint's speed limit
        self.max_speed_motor = 0  # the motor (1..6) that made it
        self.max_spline_accel = 0.0  # largest per-tick speed change while playing splines
        self.calibrations = 0  # calibration commands (C flag 4) received
        self.moving_status = p.STATUS_MOVING  # what a moving motor reports (KNI: 16 or 24)
        self.queue_size = QUEUE_SIZE
        self.refuse_within = 0  # refuse move and spline targets this close to the range's ends
        self.refuse_with_failure = False  # ... with a C reply's success byte 0, not with 0xC0
        self.status_override: dict[int, int] = {}  # motor -> status reported regardless
        self._last_row: tuple | None = None
        self._clock = clock
        self._t0 = clock()
        self._tick = 0.0
        self._lock = threading.RLock()
        model = EncoderModel(variant)
        self.motors: list[_Motor] = []
        for i in range(1, 7):
            if i <= 5:
                lo, hi = model.encoder_range(i)
                vmax = model.speed_limit_enc(i)
            else:
                lo, hi = 12240 - 500, ENCODER_OFFSETS[5]
                vmax = model.gripper_speed_limit_enc()
            boot = (lo + hi) / 2.0  # incremental encoders: an arbitrary value until calibrated
            self.motors.append(_Motor(i, boot, lo, hi, vmax, nominal_speed=vmax, target=boot))
        if calibrated:
            self.finish_calibration_now()

    # ------------------------------------------------------------------ clock
    def now_tick(self) -> float:
        return (self._clock() - self._t0) * self.time_scale / p.TICK_S

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
            if m.status == p.STATUS_CALIBRATING or (m.running and m.queue):
                return False
            if (m.status in p.MOVING_STATUSES or m.status == p.STATUS_HOLDING) and (
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
        before, was_calibrating = m.pos, m.status == p.STATUS_CALIBRATING
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
        if m.status in (p.STATUS_OFF, p.STATUS_COLLISION, p.STATUS_INVALID):
            m.vel = 0.0
            return
        if m.status == p.STATUS_CALIBRATING:
            if tick >= m.calib_end:
                self._calibrated(m)
            return
        if m.running and m.queue:
            seg, prev = m.queue[0], m.pos
            local = tick - m.seg_start
            while m.queue and local >= m.queue[0].duration:
                seg = m.queue.popleft()
                m.seg_start += seg.duration
                local = tick - m.seg_start
                m.pos = float(seg.target)
            if m.queue:
                new = evaluate(m.queue[0], local)
                m.vel, m.pos = new - prev, new  # the step of this tick, across a segment's end too
                m.status = self._playing_status(m)
            else:
                m.running, m.vel, m.target = False, 0.0, m.pos
                m.status = p.STATUS_SPLINE_DONE
            return
        if m.running:  # started with an empty queue
            m.running = False
        # Position control towards the target: trapezoidal speed profile.
        err = m.target - m.pos
        if abs(err) < 0.5 and abs(m.vel) <= m.accel_limit:
            m.pos, m.vel = m.target, 0.0
            if m.status in p.MOVING_STATUSES:
                m.status = p.STATUS_HOLDING
            return
        want = math.copysign(min(m.speed_limit, math.sqrt(2.0 * m.accel_limit * abs(err))), err)
        dv = max(-m.accel_limit, min(m.accel_limit, want - m.vel))
        m.vel += dv
        step = m.vel
        if abs(step) >= abs(err) and step * err > 0:
            step = err
        new = m.pos + step
        if m.index == 6 and self.gripper_stall_at is not None and err < 0:
            if new <= self.gripper_stall_at:  # fingers squeeze a block: stuck, still pushing
                new, m.vel = max(float(self.gripper_stall_at), min(m.pos, new)), 0.0
        m.pos = max(float(m.lo), min(float(m.hi), new))

    def _calibrated(self, m: _Motor) -> None:
        m.pos = float(ENCODER_OFFSETS[m.index - 1])
        m.target, m.vel = m.pos, 0.0
        m.calibrated = True
        m.status = p.STATUS_HOLDING

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
                if m.status != p.STATUS_OFF:
                    m.status = p.STATUS_COLLISION
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
        return p.STATUS_BUFFER_FULL if len(m.queue) >= self.queue_size else self.moving_status

    # ------------------------------------------------------------------ commands
    def handle(self, payload: bytes) -> bytes:
        """Reply payload to one request payload, or b'\\xc0' when the command is refused."""
        with self._lock:
            self.advance()
            cmd = payload[0]
            try:
                expected = p.REQUEST_LENGTHS.get(cmd)
                if expected is None:
                    raise Refusal(-1, 0, "Unknown command")
                if len(payload) != expected:
                    raise Refusal(-2, 0, f"Wrong length for this command ({len(payload)})")
                return self._dispatch(cmd, payload)
            except Refusal as r:
                self.last_error = (cmd, r.code, r.axis, r.message)
                return bytes((p.ERROR_BYTE,))

    def error_reply(self) -> bytes:
        with self._lock:
            cmd, code, axis, message = self.last_error
            return p.encode_error_reply(cmd, code, axis, message)

    def _motor(self, ident: int) -> _Motor:
        if not 1 <= ident <= 6:
            raise Refusal(-4, ident, f"Invalid motor {ident}")
        return self.motors[ident - 1]

    def _dispatch(self, cmd: int, pl: bytes) -> bytes:
        if cmd == ord("Z"):
            return b"z"
        if cmd == ord("B"):
            return bytes((ord("b"), *MASTER_VERSION))
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
            vel = int(max(p.INT16_MIN, min(p.INT16_MAX, round(m.vel))))
            return b"d" + struct.pack(">BBhhB", m.index, self._reported(m),
                                      int(round(m.pos)), vel, pwm)
        if cmd == ord("C"):
            return self._motor_command(pl)
        if cmd == ord("S"):
            return self._limits(pl)
        if cmd == ord("G"):
            motor, seg = p.decode_spline_one(pl)
            m = self._motor(motor)
            self._check_spline(m, seg, len(m.queue) + len(m.pending))
            m.pending.append(seg)
            return bytes((ord("g"), motor))
        if cmd == ord("G") + 128:
            now = self._tick
            for m in self.motors:
                if m.pending:
                    self._start_queue(m, now)
                    m.queue.extend(m.pending)
                    m.pending.clear()
            return bytes((ord("g") + 128, 1))
        if cmd == ord("H"):
            segments, activity, _exact = p.decode_spline_all(pl)
            for m, seg in zip(self.motors, segments, strict=True):
                self._check_spline(m, seg, len(m.queue))
            row = tuple(seg.values() for seg in segments)
            if any(m.last_row_reset for m in self.motors):
                self._last_row = None
                for m in self.motors:
                    m.last_row_reset = False
            holding = all(sg.p1 == sg.p2 == sg.p3 == 0 and sg.p0 == sg.target for sg in segments)
            if row == self._last_row and not holding:  # a repeated hold moves nothing
                self.duplicated_segments += 1
            self._last_row = row
            for m, seg in zip(self.motors, segments, strict=True):
                m.queue.append(seg)
                if activity != p.ACTIVITY_QUEUE:
                    self._start_queue(m, self._tick)
                if m.running:
                    m.status = self._playing_status(m)
            return bytes((ord("h"), 1, activity))
        if cmd == ord("A"):
            self.collision_detection = bool(pl[2])
            return bytes((ord("a"), pl[2]))
        if cmd == ord("E"):
            return bytes((ord("e"), pl[1])) + bytes(16)
        raise Refusal(-1, 0, "Unknown command")

    def _start_queue(self, m: _Motor, now: float) -> None:
        if not m.running:
            m.running = True
            m.seg_start = m.run_start = now
            m.status = self._playing_status(m)

    def _near_limit(self, m: _Motor, target: float) -> bool:
        """A target ``refuse_within`` encoders or closer to the ends of the motor's range."""
        return self.refuse_within > 0 and not (
            m.lo + self.refuse_within <= target <= m.hi - self.refuse_within
        )

    def _check_spline(self, m: _Motor, seg: p.SplineSegment, queued: int) -> None:
        if not m.calibrated:
            raise Refusal(-3, m.index, "Axis not calibrated")
        if m.status == p.STATUS_COLLISION:
            raise Refusal(-10, m.index, "Axis stopped by a collision: hold it first")
        if queued >= self.queue_size:
            raise Refusal(-6, m.index, "Move buffer full")
        if self._near_limit(m, seg.target) and seg.target != seg.p0:
            raise Refusal(-11, m.index, "Target too close to the limit")
        if seg.duration <= 0:
            raise Refusal(-7, m.index, "Spline duration must be positive")
        c = seg.coefficients()
        if cubic_speed_max(c[1], c[2], c[3], seg.duration) > m.speed_limit * 1.05 + 1.0:
            raise Refusal(-8, m.index, "Spline faster than the speed limit")

    def _motor_command(self, pl: bytes) -> bytes:
        _, ident, flag, pos = struct.unpack(">BBBh", pl)
        set_encoder = ident >= p.SET_ENCODER_OFFSET
        ident &= 0x7F
        targets = self.motors if ident == p.ALL_MOTORS else [self._motor(ident)]
        if set_encoder:
            for m in targets:
                m.stop_motion()
                m.pos = m.target = float(pos)
                m.calibrated = True
            return bytes((ord("c"), 1, ident))
        if flag == p.FLAG_OFF:
            for m in targets:
                m.stop_motion()
                m.status = p.STATUS_OFF
        elif flag == p.FLAG_CALIBRATE:
            self.calibrations += 1
            for m in targets:
                m.stop_motion()
                m.calibrated = False
                m.status = p.STATUS_CALIBRATING
                m.calib_end = self._tick + self.calibration_s / p.TICK_S
        elif flag == p.FLAG_FLUSH:
            for m in targets:
                m.stop_motion()
                if m.status in p.MOVING_STATUSES or m.status == p.STATUS_SPLINE_DONE:
                    m.status = p.STATUS_HOLDING
        elif flag in (p.FLAG_HOLD, p.FLAG_MOVE):
            if ident == p.ALL_MOTORS:
                raise Refusal(-4, 0, "Motor 0 is not valid for hold or move")
            m = targets[0]
            if flag == p.FLAG_MOVE:
                if not m.calibrated:
                    raise Refusal(-3, m.index, "Axis not calibrated")
                if m.status == p.STATUS_COLLISION:
                    raise Refusal(-10, m.index, "Axis stopped by a collision: hold it first")
                if self._near_limit(m, pos):
                    if self.refuse_with_failure:
                        return bytes((ord("c"), 0, ident))
                    raise Refusal(-11, m.index, "Target too close to the limit")
            m.stop_motion()
            m.target = float(max(m.lo, min(m.hi, pos))) if m.calibrated else float(pos)
            if not m.calibrated:
                m.pos = m.target = m.pos  # uncalibrated hold: stay (the encoders mean nothing)
            m.status = self.moving_status if flag == p.FLAG_MOVE else p.STATUS_HOLDING
        else:
            raise Refusal(-5, ident, f"Unknown motor flag {flag}")
        return bytes((ord("c"), 1, ident))

    def _limits(self, pl: bytes) -> bytes:
        _, ident, sub, a, b, c = pl
        m = self._motor(ident)
        if sub == p.SUB_SPEED_LIMIT:
            if not 1 <= a <= p.FIRMWARE_SPEED_LIMIT:
                raise Refusal(-9, ident, f"Speed limit {a} outside 1..{p.FIRMWARE_SPEED_LIMIT}")
            m.speed_limit = float(a)
        elif sub == p.SUB_ACCEL_LIMIT:
            if not 1 <= a <= 4:
                raise Refusal(-9, ident, f"Acceleration limit {a} outside 1..4")
            m.accel_limit = float(a)
        return bytes((ord("s"), ident, sub, a, b, c))
