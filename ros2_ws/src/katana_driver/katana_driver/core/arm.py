"""The arm worker: one thread owns the link; callers post jobs and read cached state (ROS-free).

All serial/TCP I/O happens in this thread, so a ROS executor never waits on the wire. The
thread polls positions at ``poll_rate`` (status flags too while something moves, otherwise
every ``status_every`` polls), runs posted jobs between polls, streams trajectory segments
into the controller's move buffer a little ahead of time (core.streaming), and reconnects
after a lost link. After a lost link the arm is frozen on reconnection.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any, TypeVar

from . import protocol as p
from .client import KatanaClient
from .encoders import GRIPPER_OPEN_RAD, EncoderModel
from .streaming import Stream, TrajectoryStreaming
from .transport import LinkDown, NoReply, Transport, TransportError

T = TypeVar("T")
Log = Callable[[str, str], None]  # (level, message); level: debug, info, warn, error

#: after calibration every arm motor backs off its stop by this much, as the KNI does, so the
#: arm rests inside the joint limits (at the stop, rounding puts it a hair outside them)
CALIBRATION_BACKOFF_RAD = 0.01


@dataclass
class ArmState:
    """One poll of the arm; positions/velocities in joint_states order (seven joints)."""

    stamp: float  # time.monotonic() of the poll
    encoders: list[int]
    positions: list[float]
    velocities: list[float]
    status: list[int]  # last known status flags of motors 1..6
    status_stamp: float  # when ``status`` was read


class NotConnected(TransportError):
    """The worker has no link to the controller right now."""


class ArmWorker(TrajectoryStreaming):
    """Owns a KatanaClient in a thread; thread-safe methods for the node."""

    def __init__(
        self,
        transport: Transport,
        model: EncoderModel,
        poll_rate: float = 25.0,
        calibrate_on_start: bool = True,
        collision_detection: bool = True,
        reconnect_period: float = 1.0,
        calibration_timeout: float = 120.0,
        status_every: int = 10,
        on_state: Callable[[ArmState], None] | None = None,
        log: Log | None = None,
    ) -> None:
        self.client = KatanaClient(transport)
        self.transport = transport
        self.model = model
        self.period = 1.0 / poll_rate
        self.calibrate_on_start = calibrate_on_start
        self.collision_detection = collision_detection
        self.reconnect_period = reconnect_period
        self.calibration_timeout = calibration_timeout
        self.status_every = max(1, status_every)
        self.on_state = on_state
        self._log_fn = log
        self.connected = False
        self.calibrated = False
        self.identification = ""
        self.link_error = "not connected yet"
        self.collision_message = ""
        self.polls = 0
        self.link_losses = 0
        self._calibrated_once = False
        self._freeze_on_connect = False
        self._jobs: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._cond = threading.Condition()
        self._state: ArmState | None = None
        self._status = [p.STATUS_INVALID] * 6
        self._status_stamp = 0.0
        self._stream: Stream | None = None
        self._busy = 0
        self._busy_lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name="katana-arm-worker", daemon=True)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout: float = 3.0) -> None:
        self._stop.set()
        self._thread.join(timeout=timeout)
        self.transport.close()

    def _log(self, level: str, message: str) -> None:
        if self._log_fn is not None:
            try:
                self._log_fn(level, message)
            except Exception:  # noqa: BLE001 - a logging failure must not stop the worker
                pass

    # ------------------------------------------------------------------ state for callers
    @property
    def ready(self) -> bool:
        """Connected, calibrated, and a state has been read: goals can run."""
        return self.connected and self.calibrated and self._state is not None

    @property
    def state(self) -> ArmState | None:
        with self._cond:
            return self._state

    def wait_state(self, after: float, timeout: float) -> ArmState | None:
        """The first state polled after monotonic time ``after``, or None on timeout."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while self._state is None or self._state.stamp <= after:
                remaining = deadline - time.monotonic()
                if remaining <= 0.0 or self._stop.is_set():
                    return None
                self._cond.wait(remaining)
            return self._state

    def busy(self) -> _Busy:
        """Context manager: poll status flags every cycle while a motion is watched."""
        return _Busy(self)

    # ------------------------------------------------------------------ jobs
    def submit(self, fn: Callable[[KatanaClient], T]) -> Future:
        """Run ``fn(client)`` in the worker thread; the Future holds its result or error."""
        future: Future = Future()
        if not self.connected:
            future.set_exception(NotConnected(self._not_connected_message()))
            return future
        self._jobs.put((fn, future))
        return future

    def call(self, fn: Callable[[KatanaClient], T], timeout: float = 5.0) -> T:
        """submit() and wait; raises the job's exception or TimeoutError."""
        return self.submit(fn).result(timeout=timeout)

    def _not_connected_message(self) -> str:
        return f"no connection to the Katana controller ({self.link_error})"

    def stop_motion(self) -> Future:
        """Freeze: empty the move buffers and hold every motor where it is."""
        return self.submit(self._freeze)

    # ------------------------------------------------------------------ worker thread
    def _run(self) -> None:
        next_poll = time.monotonic()
        while not self._stop.is_set():
            if not self.connected:
                if not self._connect():
                    self._stop.wait(self.reconnect_period)
                    next_poll = time.monotonic()
                    continue
            timeout = max(0.0, next_poll - time.monotonic())
            if self._stream is not None:
                timeout = min(timeout, 0.01)
            try:
                job = self._jobs.get(timeout=timeout)
            except queue.Empty:
                job = None
            try:
                if job is not None:
                    self._run_job(*job)
                if self._stream is not None:
                    self._stream_step()
                now = time.monotonic()
                if now >= next_poll:
                    # a fixed rate: a late poll is made up by the next, unless far behind
                    next_poll += self.period
                    if now - next_poll > 3.0 * self.period:
                        next_poll = now
                    self._poll()
            except TransportError as exc:
                self._link_lost(str(exc))
            except p.ControllerError as exc:
                # A refused segment (an H sent in the moment after a collision stopped the arm,
                # before a poll saw it). Uncaught, this ended the worker thread: no joint state
                # ever after (the collision test's old flake).
                self._log("error", f"the controller refused a trajectory command: {exc}")
                self._end_stream(RuntimeError(f"the controller refused the trajectory: {exc}"))
            except Exception as exc:  # noqa: BLE001 - a bug must not end the arm's only thread
                self._log("error", f"arm worker error: {exc!r}")
                self._end_stream(RuntimeError(f"driver error: {exc!r}"))
        self._fail_pending(NotConnected("the driver is shutting down"))

    def _run_job(self, fn: Callable[[KatanaClient], Any], future: Future) -> None:
        if not future.set_running_or_notify_cancel():
            return
        try:
            future.set_result(fn(self.client))
        except TransportError as exc:
            future.set_exception(exc)
            raise
        except Exception as exc:  # noqa: BLE001 - delivered to the caller
            future.set_exception(exc)

    def _connect(self) -> bool:
        try:
            self.transport.open()
            self.client.echo()
            self.identification = self.client.identification()
        except (TransportError, p.ControllerError) as exc:
            self.transport.close()
            message = str(exc)
            if message != self.link_error:
                self._log("error", f"cannot reach the Katana controller: {message}; retrying")
            self.link_error = message
            return False
        self._log("info", f"connected to {self.transport.name}: '{self.identification}'")
        if "EMULATOR" in self.identification.upper():
            self._log("warn", "the controller is the katana-emulator, not a real arm")
        try:
            self._poll(force_status=True)
            self._setup()
        except (TransportError, p.ControllerError) as exc:
            self.transport.close()
            self.link_error = f"set-up failed: {exc}"
            self._log("error", self.link_error)
            return False
        if self._freeze_on_connect:  # lost mid-motion: stop what the buffer may still play
            try:
                self._freeze(self.client)
                self._log("warn", "reconnected: froze the arm (the link was lost)")
            except (TransportError, p.ControllerError) as exc:
                self.transport.close()
                self.link_error = f"could not freeze the arm after reconnecting: {exc}"
                self._log("error", self.link_error)
                return False
        self.connected = True
        self.link_error = ""
        return True

    def _setup(self) -> None:
        self.calibrated = self._probe_calibrated()
        if not self.calibrated and self.calibrate_on_start and not self._calibrated_once:
            self._calibrate()
        elif not self.calibrated:
            self._log(
                "error",
                "the arm is not calibrated (the controller refuses moves); restart the driver "
                "with calibrate_on_startup:=true",
            )
        if self.calibrated:
            self._calibrated_once = True
        self.client.collision_detection(self.collision_detection)

    def _probe_calibrated(self) -> bool:
        """A move of the gripper motor to where it is: refused when not calibrated."""
        enc = self.client.read_positions()[5]
        try:
            self.client.move_motor(6, enc)
        except p.ControllerError as exc:
            self._log("info", f"calibration probe: {exc}")
            return False
        return True

    def _calibrate(self) -> None:
        self._log("info", "calibrating the arm (every motor runs to its stop)")
        self.client.collision_detection(False)
        self.client.calibrate()
        deadline = time.monotonic() + self.calibration_timeout
        while time.monotonic() < deadline and not self._stop.is_set():
            self._stop.wait(0.2)  # a sane polling rate (the vendor library busy-looped)
            self._poll(force_status=True)
            if all(s not in (p.STATUS_CALIBRATING, p.STATUS_OFF) for s in self._status):
                self.calibrated = True
                self._log("info", "calibration done")
                self._back_off_stops()
                return
        raise TransportError(
            f"calibration did not finish within {self.calibration_timeout:.0f} s "
            f"(status flags {self._status})"
        )

    def _back_off_stops(self) -> None:
        """Move every motor off its calibration stop into the joint limits (gripper: open)."""
        targets = [
            int(round(self.model.angle_to_encoder(i + 1, angle)))
            for i, angle in enumerate(self.model.calibration_pose(CALIBRATION_BACKOFF_RAD))
        ]
        targets.append(int(round(self.model.gripper_angle_to_encoder(GRIPPER_OPEN_RAD))))
        for motor, enc in enumerate(targets, start=1):
            try:
                self.client.move_motor(motor, enc)
            except NoReply:  # an absolute target: if lost, the state read below shows it
                pass
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and not self._stop.is_set():
            self._stop.wait(0.1)
            self._poll(force_status=True)
            encoders = self._state.encoders
            if all(abs(e - t) <= 2 for e, t in zip(encoders, targets, strict=True)):
                return
            for motor, (e, t) in enumerate(zip(encoders, targets, strict=True), start=1):
                if abs(e - t) > 2 and self._status[motor - 1] == p.STATUS_HOLDING:
                    self.client.move_motor(motor, t)  # known not taken (holding elsewhere)
        raise TransportError("the motors did not back off their calibration stops in 10 s")

    def _poll(self, force_status: bool = False) -> None:
        encoders = self.client.read_positions()
        now = time.monotonic()
        self.polls += 1
        with self._busy_lock:
            busy = self._busy > 0
        if force_status or busy or self._stream is not None or self.polls % self.status_every == 0:
            self._status = self.client.read_status()
            self._status_stamp = time.monotonic()
            if p.STATUS_COLLISION in self._status and not self.collision_message:
                self._on_collision()
            elif p.STATUS_COLLISION not in self._status:
                self.collision_message = ""
        positions = self.model.encoders_to_joint_positions(encoders)
        previous = self._state
        if previous is not None and now > previous.stamp:
            dt = now - previous.stamp
            velocities = [(a - b) / dt for a, b in zip(positions, previous.positions, strict=True)]
        else:
            velocities = [0.0] * len(positions)
        state = ArmState(
            now, encoders, positions, velocities, list(self._status), self._status_stamp
        )
        with self._cond:
            self._state = state
            self._cond.notify_all()
        if self.on_state is not None:
            try:
                self.on_state(state)
            except Exception as exc:  # noqa: BLE001 - a listener failure must not stop polling
                self._log("error", f"joint state listener failed: {exc}")

    def _on_collision(self) -> None:
        axes = [i + 1 for i, s in enumerate(self._status) if s == p.STATUS_COLLISION]
        err = None
        try:
            err = self.client.read_last_error()
        except TransportError:
            pass
        text = err.message if err is not None and err.message else "no message"
        self.collision_message = f"collision: motors {axes} stopped (controller: '{text}')"
        self._log("error", self.collision_message)
        if self._stream is not None:
            self._end_stream(RuntimeError(self.collision_message))

    def _link_lost(self, message: str) -> None:
        self.transport.close()
        self.connected = False
        self.link_losses += 1
        self._freeze_on_connect = True
        self.link_error = f"lost connection to the Katana controller ({message})"
        self._log("error", f"{self.link_error}; reconnecting every {self.reconnect_period:g} s")
        self._fail_pending(LinkDown(self.link_error))

    def _fail_pending(self, exc: Exception) -> None:
        if self._stream is not None:
            self._end_stream(exc)
        while True:
            try:
                _, future = self._jobs.get_nowait()
            except queue.Empty:
                break
            if future.set_running_or_notify_cancel():
                future.set_exception(exc)

    def _freeze(self, client: KatanaClient) -> None:
        if self._stream is not None:
            self._stream.cancelled = True
            self._end_stream(None)
        client.flush_buffers()
        encoders = client.read_positions()
        client.hold_all(encoders[:6])
        self._freeze_on_connect = False


class _Busy:
    def __init__(self, worker: ArmWorker) -> None:
        self.worker = worker

    def __enter__(self) -> ArmWorker:
        with self.worker._busy_lock:
            self.worker._busy += 1
        return self.worker

    def __exit__(self, *exc: object) -> None:
        with self.worker._busy_lock:
            self.worker._busy -= 1
