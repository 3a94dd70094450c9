"""The arm worker: one thread owns the link; callers post jobs and read cached state (ROS-free).

All serial/TCP I/O happens in this thread, so a ROS executor never waits on the wire. The
thread polls positions at ``poll_rate`` (status flags too while something moves, otherwise
every ``status_every`` polls), runs posted jobs between polls, streams trajectory segments
into the controller's move buffer a little ahead of time, and reconnects after a lost link.

Segments are never re-sent. When a segment's reply is lost (transport.NoReply) the stream
stops sending and reads the controller's status when that segment should be playing: motors
moving means it was taken (go on), motors done means it was not (the arm has stopped at the
end of the previous segment: the stream ends with an error and the goal is aborted). Before
the motion starts, a lost reply is resolved by flushing the move buffers (harmless twice) and
streaming again from the first segment. After a lost link the arm is frozen on reconnection.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any, TypeVar

from . import protocol as p
from .client import KatanaClient
from .encoders import GRIPPER_OPEN_RAD, EncoderModel
from .splines import SplinePlan, hold_segment
from .transport import LinkDown, NoReply, Transport, TransportError

T = TypeVar("T")
Log = Callable[[str, str], None]  # (level, message); level: debug, info, warn, error

START_BUFFER_TICKS = 40  # queue this much motion before starting (as the ROS 1 driver did)
LOOKAHEAD_S = 1.5  # keep segments starting within this horizon in the move buffer
MAX_IN_BUFFER = 12  # of the assumed 16-segment move buffer
CONFIRM_MARGIN_S = 0.06  # read the status this long after an unconfirmed segment should start
MAX_RESTARTS = 3  # re-streams (after a flush) of a trajectory that has not started moving
START_SLACK_ENC = 5  # encoders a motor may be from the plan's start for a re-stream
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


@dataclass
class Stream:
    """A trajectory being fed to the controller."""

    plan: SplinePlan
    gripper_enc: int
    sent: int = 0  # segments the controller is known to hold
    started_at: float | None = None  # monotonic time at which motion was started
    cancelled: bool = False
    started: Future = field(default_factory=Future)  # result: started_at
    finished_sending: Future = field(default_factory=Future)
    queue_end: float = 0.0  # estimated monotonic time at which the controller's queue runs out
    ends: list[float] = field(default_factory=list)  # estimated end of each segment taken
    unconfirmed: tuple[int, int, float, float] | None = None  # index, activity, sent, check at
    restarts: int = 0
    lost_replies: int = 0

    def duration_of(self, index: int) -> float:
        return self.plan.segments[index][0].duration * p.TICK_S

    @property
    def lag_s(self) -> float:
        """How much later than planned the controller will finish what it holds (>= 0)."""
        if self.started_at is None or self.sent == 0:
            return 0.0
        planned = self.started_at + (
            self.plan.start_ticks[self.sent - 1] * p.TICK_S + self.duration_of(self.sent - 1)
        )
        return max(0.0, self.queue_end - planned)


class NotConnected(TransportError):
    """The worker has no link to the controller right now."""


class ArmWorker:
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

    def start_trajectory(self, plan: SplinePlan) -> Stream:
        """Begin streaming ``plan``; ``stream.started`` resolves when the arm was told to go."""
        state = self.state
        gripper = state.encoders[5] if state is not None else 0
        stream = Stream(plan=plan, gripper_enc=gripper)
        future = self.submit(lambda client: self._begin_stream(client, stream))
        future.add_done_callback(lambda f: _forward_error(f, stream))
        return stream

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

    # ------------------------------------------------------------------ streaming
    def _begin_stream(self, client: KatanaClient, stream: Stream) -> None:
        if self._stream is not None:
            raise RuntimeError("another trajectory is running")
        crashed = [i for i, s in enumerate(self._status) if s == p.STATUS_COLLISION]
        if crashed:
            self._log(
                "warn",
                f"motors {[i + 1 for i in crashed]} were stopped by a collision; "
                "unblocking them before the new trajectory",
            )
            encoders = client.read_positions()
            client.hold_all(encoders)
            self.collision_message = ""
            self._status = client.read_status()
        client.flush_buffers()
        # Motor 6 rides along in every H row as a hold segment: hold it where it is now (a
        # position cached before a finishing gripper move made the fingers jump back).
        stream.gripper_enc = client.read_positions()[5]
        self._stream = stream
        try:
            self._stream_step()
        except p.ControllerError as exc:
            self._end_stream(RuntimeError(f"the controller refused the trajectory: {exc}"))

    def _stream_step(self) -> None:
        stream = self._stream
        if stream is None:
            return
        if stream.cancelled:
            self._end_stream(None)
            return
        if stream.unconfirmed is not None and not self._confirm(stream):
            return
        plan = stream.plan
        n = len(plan.segments)
        while stream.sent < n and self._stream is stream:
            i = stream.sent
            now = time.monotonic()
            if stream.started_at is not None:
                in_buffer = sum(1 for e in stream.ends if e > now)
                if in_buffer >= MAX_IN_BUFFER or stream.queue_end - now > LOOKAHEAD_S:
                    return
            if i == n - 1:
                activity = p.ACTIVITY_LAST
            elif stream.started_at is None and plan.start_ticks[i + 1] < START_BUFFER_TICKS:
                activity = p.ACTIVITY_QUEUE
            else:
                activity = p.ACTIVITY_START
            row = plan.segments[i]
            gripper = hold_segment(stream.gripper_enc, row[0].duration)
            sent_at = time.monotonic()
            try:
                self.client.send_spline_all([*row, gripper], activity)
            except NoReply as exc:
                stream.lost_replies += 1
                begins = max(stream.queue_end, sent_at) if stream.started_at else sent_at
                stream.unconfirmed = (i, activity, sent_at, begins + CONFIRM_MARGIN_S)
                self._log("warn", f"segment {i}: {exc}; reading the controller's state")
                return
            self._taken(stream, i, activity, sent_at)
            if stream.started_at is not None:
                break  # one segment per turn once moving, so that polls are never starved
        if stream.sent >= n:
            self._end_stream(None)

    def _taken(self, stream: Stream, i: int, activity: int, sent_at: float) -> None:
        """Segment ``i`` is in the controller's buffer."""
        stream.sent = i + 1
        if stream.started_at is not None:
            stream.queue_end = max(stream.queue_end, sent_at) + stream.duration_of(i)
            stream.ends.append(stream.queue_end)
        elif activity != p.ACTIVITY_QUEUE:  # this segment started the motion
            stream.started_at = sent_at
            stream.queue_end = sent_at
            for k in range(i + 1):
                stream.queue_end += stream.duration_of(k)
                stream.ends.append(stream.queue_end)
            stream.started.set_result(sent_at)

    def _confirm(self, stream: Stream) -> bool:
        """Learn from the controller whether the unconfirmed segment was taken; True: go on."""
        i, activity, sent_at, check_at = stream.unconfirmed
        if stream.started_at is None and activity == p.ACTIVITY_QUEUE:
            return self._restart(stream, f"the reply to queued segment {i} was lost")
        if time.monotonic() < check_at:
            return False
        status = self.client.read_status()  # answered after the segment: the link is in order
        self._status, self._status_stamp = status, time.monotonic()
        encoders = self.client.read_positions()
        stream.unconfirmed = None
        row = stream.plan.segments[i]
        at_end = all(abs(e - seg.target) <= START_SLACK_ENC
                     for e, seg in zip(encoders, row, strict=False))
        moved = any(seg.target != seg.p0 for seg in row)
        # Moving: it plays (nothing else is queued after it). Done at its end (a late answer
        # to the status read): it played. Done where it starts: the queue ran dry without it.
        if all(s == p.STATUS_MOVING for s in status[:5]) or (at_end and moved):
            self._log("info", f"segment {i} was taken (the motors play or played it)")
            self._taken(stream, i, activity, sent_at)
            return True
        if stream.started_at is None:
            return self._restart(stream, f"segment {i} did not start the motion")
        self._end_stream(RuntimeError(
            f"the controller did not take trajectory segment {i} (its reply was lost; the "
            f"motors report {status[:5]}); the arm stopped at the end of segment {i - 1}"
        ))
        return False

    def _restart(self, stream: Stream, why: str) -> bool:
        """Nothing moves yet: flush the buffers (harmless twice) and stream from segment 0."""
        stream.unconfirmed = None
        if stream.restarts >= MAX_RESTARTS:
            self._end_stream(RuntimeError(f"{why}; gave up after {MAX_RESTARTS} restarts"))
            return False
        stream.restarts += 1
        self._log("warn", f"{why}; flushing the move buffers and sending the trajectory again")
        self.client.flush_buffers()
        encoders = self.client.read_positions()
        first = stream.plan.segments[0]
        moved = max(abs(e - seg.p0) for e, seg in zip(encoders, first, strict=False))
        if moved > START_SLACK_ENC:  # it did move: streaming from the start would jump back
            self.client.hold_all(encoders[:6])
            self._end_stream(RuntimeError(f"{why}, and the arm had moved; stopped it"))
            return False
        stream.sent, stream.ends = 0, []
        return True

    def _end_stream(self, error: Exception | None) -> None:
        stream, self._stream = self._stream, None
        if stream is None:
            return
        for future in (stream.started, stream.finished_sending):
            if not future.done():
                if error is None:
                    future.set_result(stream.started_at)
                else:
                    future.set_exception(error)

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


def _forward_error(future: Future, stream: Stream) -> None:
    exc = future.exception()
    if exc is not None:
        for f in (stream.started, stream.finished_sending):
            if not f.done():
                f.set_exception(exc)
