"""Katana EMULATOR: a protocol-level test double of the Katana controller. NOT a robot.

It speaks the controller's wire protocol on loopback TCP (and on a pseudo-terminal for the
serial Katana 300) and moves six simulated motors: speed and acceleration limits, a spline
queue, calibration state (uncalibrated at boot: moves are refused with "Axis not calibrated"),
status flags, collision injection, and fault knobs (latency, split, silent and corrupted
replies). The vendor shipped a simulator speaking the same protocol for the same purpose:
testing drivers and dry runs without an arm. It knows nothing of blocks, gravity or the
real firmware's timing, so passing against it says the driver speaks the protocol as
documented in shared/KATANA.md, not that an arm will do the same.

Model time is wall time times ``time_scale`` (tests run it faster than real time).
"""

from __future__ import annotations

import argparse
import math
import os
import random
import select
import socket
import struct
import sys
import threading
import time
import tty
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from katana_driver.core import protocol as p
from katana_driver.core.encoders import EncoderModel
from katana_driver.core.splines import cubic_speed_max, evaluate

BANNER = "KATANA EMULATOR: a protocol-level test double, NOT a robot arm"
QUEUE_SIZE = 16  # move buffer per motor (the real size is unconfirmed; KATANA.md assumes 16)
ENCODER_OFFSETS = (31000, -31000, -31000, 31000, 31000, 31000)


class Refusal(Exception):
    """The emulated controller refuses a command (answered with 0xC0)."""

    def __init__(self, code: int, axis: int, message: str) -> None:
        super().__init__(message)
        self.code, self.axis, self.message = code, axis, message


@dataclass
class Faults:
    """Fault knobs; all can be changed while the emulator runs."""

    latency_s: float = 0.0  # delay before each reply
    split_replies: bool = False  # send each reply in two writes
    split_delay_s: float = 0.005  # pause between the two parts
    silent_rate: float = 0.0  # probability that a reply is never sent
    corrupt_rate: float = 0.0  # probability that a reply's CRC is corrupted
    silent_next: int = 0  # the next N replies are not sent
    corrupt_next: int = 0  # the next N replies have a corrupted CRC
    seed: int = 0
    _rng: random.Random = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._rng = random.Random(self.seed)

    def take_silent(self) -> bool:
        if self.silent_next > 0:
            self.silent_next -= 1
            return True
        return self.silent_rate > 0.0 and self._rng.random() < self.silent_rate

    def take_corrupt(self) -> bool:
        if self.corrupt_next > 0:
            self.corrupt_next -= 1
            return True
        return self.corrupt_rate > 0.0 and self._rng.random() < self.corrupt_rate


@dataclass
class _Motor:
    index: int  # 1..6
    pos: float
    lo: int
    hi: int
    speed_limit: float  # encoders per tick
    accel_limit: float = 2.0  # encoders per tick^2 (the firmware's unit is unconfirmed)
    status: int = p.STATUS_OFF
    calibrated: bool = False
    target: float = 0.0
    vel: float = 0.0
    queue: deque = field(default_factory=deque)  # started or startable SplineSegments
    pending: list = field(default_factory=list)  # queued with G, waiting for G+128
    running: bool = False
    seg_start: float = 0.0  # tick at which queue[0] started
    calib_end: float = 0.0

    def stop_motion(self) -> None:
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
        self.commands_seen = 0
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
            self.motors.append(_Motor(i, boot, lo, hi, vmax, target=boot))
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
            if m.status in (p.STATUS_MOVING, p.STATUS_HOLDING) and (
                abs(m.target - m.pos) > 1e-9 or m.vel != 0.0
            ):
                return False
        return True

    def _step(self, m: _Motor, tick: float) -> None:
        if m.status in (p.STATUS_OFF, p.STATUS_COLLISION, p.STATUS_INVALID):
            m.vel = 0.0
            return
        if m.status == p.STATUS_CALIBRATING:
            if tick >= m.calib_end:
                self._calibrated(m)
            return
        if m.running and m.queue:
            seg = m.queue[0]
            local = tick - m.seg_start
            while m.queue and local >= m.queue[0].duration:
                seg = m.queue.popleft()
                m.seg_start += seg.duration
                local = tick - m.seg_start
                m.pos = float(seg.target)
            if m.queue:
                new = evaluate(m.queue[0], local)
                m.vel, m.pos = new - m.pos, new
                m.status = p.STATUS_MOVING
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
            if m.status == p.STATUS_MOVING:
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
            return [m.status for m in self.motors]

    # ------------------------------------------------------------------ commands
    def handle(self, payload: bytes) -> bytes:
        """Reply payload to one request payload, or b'\\xc0' when the command is refused."""
        with self._lock:
            self.advance()
            self.commands_seen += 1
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
            return bytes((ord("b"), 3 if self.katana_type == 300 else 4, 0))
        if cmd == ord("Y"):
            text = f"{BANNER} (Katana {self.katana_type} {self.variant})".encode()
            return b"y" + text[:82].ljust(83, b"\x00")
        if cmd == ord("N"):
            if pl[1] == 3:
                return b"n" + struct.pack(">6h", *(int(round(m.pos)) for m in self.motors))
            if pl[1] == 1:
                return b"n" + bytes(m.status for m in self.motors) + bytes(6)
            raise Refusal(-1, 0, f"Unknown N sub-command {pl[1]}")
        if cmd == ord("D"):
            m = self._motor(pl[1])
            pwm = int(max(-100, min(100, round(100.0 * m.vel / max(m.speed_limit, 1.0)))))
            vel = int(max(p.INT16_MIN, min(p.INT16_MAX, round(m.vel))))
            return b"d" + struct.pack(">BBhhb", m.index, m.status, int(round(m.pos)), vel, pwm)
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
            for m, seg in zip(self.motors, segments, strict=True):
                m.queue.append(seg)
                if activity != p.ACTIVITY_QUEUE:
                    self._start_queue(m, self._tick)
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
            m.seg_start = now
            m.status = p.STATUS_MOVING

    def _check_spline(self, m: _Motor, seg: p.SplineSegment, queued: int) -> None:
        if not m.calibrated:
            raise Refusal(-3, m.index, "Axis not calibrated")
        if m.status == p.STATUS_COLLISION:
            raise Refusal(-10, m.index, "Axis stopped by a collision: hold it first")
        if queued >= QUEUE_SIZE:
            raise Refusal(-6, m.index, "Move buffer full")
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
            for m in targets:
                m.stop_motion()
                m.calibrated = False
                m.status = p.STATUS_CALIBRATING
                m.calib_end = self._tick + self.calibration_s / p.TICK_S
        elif flag == p.FLAG_FLUSH:
            for m in targets:
                m.stop_motion()
                if m.status in (p.STATUS_MOVING, p.STATUS_SPLINE_DONE):
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
            m.stop_motion()
            m.target = float(max(m.lo, min(m.hi, pos))) if m.calibrated else float(pos)
            if not m.calibrated:
                m.pos = m.target = m.pos  # uncalibrated hold: stay (the encoders mean nothing)
            m.status = p.STATUS_MOVING if flag == p.FLAG_MOVE else p.STATUS_HOLDING
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


class _FrameParser:
    """Splits a byte stream into request payloads and raw 0xC1 queries; drops garbage."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.bad_frames = 0

    def feed(self, data: bytes) -> list[bytes | None]:
        """Complete requests in order: a payload, or None for the raw error query."""
        self.buf += data
        out: list[bytes | None] = []
        while self.buf:
            if self.buf[0] == p.HEADER:
                if len(self.buf) < 3:
                    break
                if self.buf[1] != p.ADDRESS:
                    del self.buf[0]
                    continue
                n = self.buf[2] + 5
                if len(self.buf) < n:
                    break
                frame = bytes(self.buf[:n])
                del self.buf[:n]
                try:
                    out.append(p.parse_request(frame))
                except p.ProtocolError:
                    self.bad_frames += 1  # a corrupted request gets no reply: the client retries
            elif self.buf[0] == 0x00:
                if len(self.buf) < len(p.ERROR_QUERY):
                    if p.ERROR_QUERY.startswith(bytes(self.buf)):
                        break
                    del self.buf[0]
                    continue
                if bytes(self.buf[:4]) == p.ERROR_QUERY:
                    del self.buf[:4]
                    out.append(None)
                else:
                    del self.buf[0]
            else:
                del self.buf[0]
        return out


class KatanaEmulator:
    """The emulated controller behind a TCP socket and/or a pseudo-terminal."""

    def __init__(self, model: KatanaModel | None = None, faults: Faults | None = None) -> None:
        self.model = model or KatanaModel()
        self.faults = faults or Faults()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._listener: socket.socket | None = None
        self._conn: socket.socket | None = None
        self._conn_lock = threading.Lock()
        self._pty: tuple[int, int] | None = None
        self.address: tuple[str, int] | None = None
        self.serial_device: str | None = None
        self.replies_sent = 0

    # ------------------------------------------------------------------ replies
    def _respond(self, parser: _FrameParser, data: bytes, write: Callable[[bytes], None]) -> None:
        for request in parser.feed(data):
            if request is None:
                reply = self.model.error_reply()
            else:
                reply = p.frame_reply(self.model.handle(request))
            self._send(reply, write)

    def _send(self, reply: bytes, write: Callable[[bytes], None]) -> None:
        f = self.faults
        if f.take_silent():
            return
        if f.take_corrupt():
            reply = reply[:-1] + bytes(((reply[-1] ^ 0x5A),))
        if f.latency_s > 0.0:
            time.sleep(f.latency_s)
        if f.split_replies and len(reply) > 1:
            half = len(reply) // 2
            write(reply[:half])
            time.sleep(f.split_delay_s)
            write(reply[half:])
        else:
            write(reply)
        self.replies_sent += 1

    # ------------------------------------------------------------------ TCP
    def serve_tcp(self, host: str = "127.0.0.1", port: int = 0) -> tuple[str, int]:
        """Listen on ``host:port`` (0: any free port); one client at a time, like the arm."""
        listener = socket.create_server((host, port), reuse_port=False)
        listener.settimeout(0.1)
        self._listener = listener
        self.address = listener.getsockname()[:2]
        self._spawn(self._tcp_loop, "katana-emulator-tcp")
        return self.address

    def _tcp_loop(self) -> None:
        assert self._listener is not None
        while not self._stop.is_set():
            try:
                conn, _ = self._listener.accept()
            except (TimeoutError, OSError):
                continue
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            conn.settimeout(0.1)
            with self._conn_lock:
                self._conn = conn
            parser = _FrameParser()
            try:
                while not self._stop.is_set():
                    try:
                        data = conn.recv(4096)
                    except TimeoutError:
                        continue
                    if not data:
                        break
                    self._respond(parser, data, conn.sendall)
            except OSError:
                pass
            finally:
                with self._conn_lock:
                    self._conn = None
                try:
                    conn.close()
                except OSError:
                    pass

    def drop_connection(self) -> None:
        """Close the current client connection (a pulled cable); new connections still work."""
        with self._conn_lock:
            conn = self._conn
        if conn is not None:
            try:
                conn.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    # ------------------------------------------------------------------ serial (pty)
    def serve_pty(self) -> str:
        """Open a pseudo-terminal; the driver opens the returned device like a serial port."""
        master, slave = os.openpty()
        tty.setraw(slave)
        self._pty = (master, slave)
        self.serial_device = os.ttyname(slave)
        self._spawn(self._pty_loop, "katana-emulator-pty")
        return self.serial_device

    def _pty_loop(self) -> None:
        assert self._pty is not None
        master = self._pty[0]
        parser = _FrameParser()

        def write(data: bytes) -> None:
            os.write(master, data)

        while not self._stop.is_set():
            ready, _, _ = select.select([master], [], [], 0.1)
            if not ready:
                continue
            try:
                data = os.read(master, 4096)
            except OSError:
                continue
            self._respond(parser, data, write)

    # ------------------------------------------------------------------ lifecycle
    def _spawn(self, target: Callable[[], None], name: str) -> None:
        thread = threading.Thread(target=target, name=name, daemon=True)
        thread.start()
        self._threads.append(thread)

    def stop(self) -> None:
        self._stop.set()
        self.drop_connection()
        for thread in self._threads:
            thread.join(timeout=2.0)
        if self._listener is not None:
            self._listener.close()
        if self._pty is not None:
            for fd in self._pty:
                try:
                    os.close(fd)
                except OSError:
                    pass

    def __enter__(self) -> KatanaEmulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="katana-emulator",
        description=f"{BANNER}. Speaks the Katana controller protocol for tests and dry runs.",
    )
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (loopback)")
    parser.add_argument("--port", type=int, default=5566, help="TCP port (0: any free port)")
    parser.add_argument("--serial", action="store_true", help="also open a pseudo-terminal")
    parser.add_argument("--type", type=int, default=450, choices=(300, 400, 450))
    parser.add_argument("--variant", default="6M180", choices=("6M180", "6M90A", "6M90B"))
    parser.add_argument("--time-scale", type=float, default=1.0, help="model s per wall s")
    parser.add_argument("--calibration-time", type=float, default=4.0, help="model seconds")
    parser.add_argument("--calibrated", action="store_true", help="start calibrated")
    parser.add_argument("--latency", type=float, default=0.0, help="seconds before each reply")
    parser.add_argument("--split", action="store_true", help="send replies in two parts")
    parser.add_argument("--silent-rate", type=float, default=0.0, help="fraction of lost replies")
    parser.add_argument("--corrupt-rate", type=float, default=0.0, help="fraction of bad CRCs")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    model = KatanaModel(
        katana_type=args.type,
        variant=args.variant,
        time_scale=args.time_scale,
        calibration_s=args.calibration_time,
        calibrated=args.calibrated,
    )
    faults = Faults(
        latency_s=args.latency,
        split_replies=args.split,
        silent_rate=args.silent_rate,
        corrupt_rate=args.corrupt_rate,
        seed=args.seed,
    )
    emulator = KatanaEmulator(model, faults)
    print("=" * 72, flush=True)
    print(BANNER, flush=True)
    print("Use it to test the driver and to dry-run the experiment; it moves no arm.", flush=True)
    try:
        host, port = emulator.serve_tcp(args.host, args.port)
    except OSError as exc:
        print(f"katana-emulator: cannot listen on {args.host}:{args.port}: {exc}", file=sys.stderr)
        return 1
    print(f"listening on tcp {host}:{port} (Katana {args.type} {args.variant})", flush=True)
    if args.serial:
        print(f"serial (pseudo-terminal): {emulator.serve_pty()}", flush=True)
    print("=" * 72, flush=True)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        emulator.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
