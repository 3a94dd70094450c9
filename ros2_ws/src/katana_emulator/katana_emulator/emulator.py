"""Katana EMULATOR: a protocol-level test double of the Katana controller. NOT a robot.

It speaks the controller's wire protocol on loopback TCP (and on a pseudo-terminal for the
serial Katana 300) in front of the motor model of katana_emulator.model, with fault knobs
(latency, split, silent and corrupted replies, replies to spline commands delayed, a silent or
frozen controller). The vendor shipped a simulator speaking the same protocol for the same
purpose: testing drivers and dry runs without an arm. It is written from the facts of
docs/KATANA.md and shares no code with katana_driver, so a test against it checks the driver
against the documented controller, not against the driver's own assumptions. It knows nothing
of gravity or the real firmware's timing; of blocks it knows one thing, for dry runs: with
``--block-width-m`` closing fingers stall as on a block that wide.
"""

from __future__ import annotations

import argparse
import math
import os
import random
import select
import socket
import sys
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, field

from katana_common.cli_args import (
    float_in,
    fraction,
    listen_host,
    parse_command_line,
    tcp_port,
)

from katana_emulator import wire
from katana_emulator.arms import MAX_BLOCK_WIDTH_M, MODELS, VARIANTS
from katana_emulator.model import BANNER, KatanaModel

__all__ = ["BANNER", "Faults", "KatanaEmulator", "KatanaModel", "main"]


@dataclass
class Faults:
    """Fault knobs; all can be changed while the emulator runs."""

    latency_s: float = 0.0  # delay before each reply
    split_replies: bool = False  # send each reply in two writes
    split_delay_s: float = 0.005  # pause between the two parts
    silent_rate: float = 0.0  # probability that a reply is never sent
    corrupt_rate: float = 0.0  # probability that a reply's CRC is corrupted
    silent_next: int = 0  # the next N replies are not sent
    spline_latency_s: float = 0.0  # extra delay before replies to spline commands (G, H)
    silent_until: float = 0.0  # time.monotonic() until which no reply is sent (math.inf: ever)
    frozen_until: float = 0.0  # time.monotonic() until which the controller reads nothing
    corrupt_next: int = 0  # the next N replies have a corrupted CRC
    seed: int = 0
    _rng: random.Random = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._rng = random.Random(self.seed)

    def take_silent(self) -> bool:
        if time.monotonic() < self.silent_until:
            return True
        if self.silent_next > 0:
            self.silent_next -= 1
            return True
        return self.silent_rate > 0.0 and self._rng.random() < self.silent_rate

    def take_corrupt(self) -> bool:
        if self.corrupt_next > 0:
            self.corrupt_next -= 1
            return True
        return self.corrupt_rate > 0.0 and self._rng.random() < self.corrupt_rate


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

    # ------------------------------------------------------------------ replies
    def _respond(self, parser: wire.FrameReader, data: bytes,
                 write: Callable[[bytes], None]) -> None:
        while time.monotonic() < self.faults.frozen_until and not self._stop.is_set():
            time.sleep(0.01)  # a frozen controller: requests wait, unread, in the link
        for request in parser.feed(data):
            if request is None:
                reply = self.model.error_reply()
            else:
                reply = wire.with_crc(self.model.handle(request))
            spline = request is not None and request[:1] in (b"G", b"H")
            self._send(reply, write, spline)

    def _send(self, reply: bytes, write: Callable[[bytes], None], spline: bool = False) -> None:
        f = self.faults
        if f.take_silent():
            return
        if f.take_corrupt():
            reply = reply[:-1] + bytes(((reply[-1] ^ 0x5A),))
        if f.latency_s > 0.0:
            time.sleep(f.latency_s)
        if spline and f.spline_latency_s > 0.0:
            time.sleep(f.spline_latency_s)
        if f.split_replies and len(reply) > 1:
            half = len(reply) // 2
            write(reply[:half])
            time.sleep(f.split_delay_s)
            write(reply[half:])
        else:
            write(reply)

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
            parser = wire.FrameReader()
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
        parser = wire.FrameReader()

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


#: the model's pace: model seconds per wall second (tests run it faster than real time)
_time_scale = float_in(0.0, 1000.0, low_open=True, what="a pace")
_model_seconds = float_in(0.0, 3600.0, what="a number of model seconds")
_reply_delay = float_in(0.0, 60.0, what="a number of seconds")
_WIDEST_M = math.floor(MAX_BLOCK_WIDTH_M * 1000.0) / 1000.0  # what the open jaws take
_block_width = float_in(0.005, _WIDEST_M, what="a block width in metres")


def build_parser() -> argparse.ArgumentParser:
    """The options, each checked while parsing (katana_common.cli_args)."""
    parser = argparse.ArgumentParser(
        prog="katana-emulator",
        description=f"{BANNER}. Speaks the Katana controller protocol for tests and dry runs.",
    )
    parser.add_argument("--host", type=listen_host, default="127.0.0.1",
                        help="address to listen on (loopback)")
    parser.add_argument("--port", type=tcp_port, default=5566,
                        help="TCP port, 0..65535 (0: any free port)")
    parser.add_argument("--serial", action="store_true", help="also open a pseudo-terminal")
    parser.add_argument("--type", type=int, default=450, choices=sorted(MODELS))
    parser.add_argument("--variant", default="6M180", choices=VARIANTS)
    parser.add_argument("--time-scale", type=_time_scale, default=1.0,
                        help="model s per wall s, (0, 1000]")
    parser.add_argument("--calibration-time", type=_model_seconds, default=4.0,
                        help="model seconds, [0, 3600]")
    parser.add_argument("--calibrated", action="store_true", help="start calibrated")
    parser.add_argument("--latency", type=_reply_delay, default=0.0,
                        help="seconds before each reply, [0, 60]")
    parser.add_argument("--split", action="store_true", help="send replies in two parts")
    parser.add_argument("--silent-rate", type=fraction, default=0.0,
                        help="fraction of lost replies, [0, 1]")
    parser.add_argument("--corrupt-rate", type=fraction, default=0.0,
                        help="fraction of bad CRCs, [0, 1]")
    parser.add_argument("--spline-latency", type=_reply_delay, default=0.0,
                        help="extra seconds before replies to spline commands (G, H), [0, 60]")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--block-width-m", type=_block_width, default=None, metavar="METRES",
                        help="closing fingers stall where a block this wide holds them, so "
                             "that grasps succeed in a dry run (default: no block; the fingers "
                             f"close until they touch), [0.005, {_WIDEST_M}]")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = parse_command_line(build_parser(), argv)

    model = KatanaModel(katana_type=args.type, variant=args.variant, time_scale=args.time_scale,
                        calibration_s=args.calibration_time, calibrated=args.calibrated,
                        block_width_m=args.block_width_m)
    faults = Faults(latency_s=args.latency, split_replies=args.split,
                    silent_rate=args.silent_rate, corrupt_rate=args.corrupt_rate,
                    spline_latency_s=args.spline_latency, seed=args.seed)
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
    if model.gripper_stall_at is not None:
        print(f"closing fingers stall at encoder {model.gripper_stall_at}, as on a "
              f"{args.block_width_m * 100:.1f} cm block", flush=True)
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
