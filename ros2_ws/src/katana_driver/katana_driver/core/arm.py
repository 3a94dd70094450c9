"""The arm worker: one thread owns the link; callers post jobs and read cached state (ROS-free).

All serial/TCP I/O happens in this thread, so a ROS executor never waits on the wire. The
thread polls positions at ``poll_rate`` (status flags too while something moves, otherwise
every ``status_every`` polls), runs posted jobs between polls, streams trajectory segments
into the controller's move buffer a little ahead of time (core.streaming), and reconnects
after a lost link. After a lost link the arm is frozen on reconnection.

Set-up on every connection (after a lost link, once the arm is frozen): the speed and
acceleration limits of every motor (``S`` 3 and 4, as the ROS 1 katana node sends them at
start-up), the calibration probe, calibration when needed (then every motor backs off its stop
to ``limit_margin`` encoders and a little more inside its range), any motor of a calibrated arm
still within the margin moved inside it, and collision detection. A command the controller
refuses during set-up (0xC0, or a ``C`` reply with success byte 0) ends the set-up: the arm is
frozen, the refusal is reported and goals are refused with it (``setup_problem``) until the
next connection's set-up passes.

With ``auto_setup`` false (katana_driver_node, a lifecycle node) a connection only opens the
link, reads the identification, the master version and the first state (configure); the set-up
runs when ``set_up()`` is called (activate). ``stop()`` ends the thread and closes the link
(cleanup); ``start()`` opens it again, and a freeze owed since a lost link is sent first.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any, TypeVar

from . import protocol as p
from .client import KatanaClient
from .encoders import DEFAULT_LIMIT_MARGIN_ENC, GRIPPER_OPEN_RAD, EncoderModel
from .streaming import Stream, TrajectoryStreaming
from .transport import LinkDown, NoReply, Transport, TransportError

T = TypeVar("T")
Log = Callable[[str, str], None]  # (level, message); level: debug, info, warn, error

#: after calibration every arm motor backs off its stop to this many encoders beyond the limit
#: margin, so that it rests at least the margin inside its range although the position control
#: may stop a few encoders short (the back-off accepts 2)
CALIBRATION_BACKOFF_SLACK_ENC = 10
#: KNI refuses a controller as a Katana 400/450 when the master version answered to ``B`` is
#: above this (KNI 4.3.0 kmlBase.h K400_OLD_PROTOCOL_THRESHOLD, CKatBase::checkKatanaType)
KNI_MAX_450_MASTER_VERSION = 3


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
        limit_margin: int = DEFAULT_LIMIT_MARGIN_ENC,
        speed_limits: Sequence[int] = (p.KNI_MAX_VELOCITY,) * 6,
        acceleration_limits: Sequence[int] = (p.KNI_MAX_ACCELERATION,) * 6,
        auto_setup: bool = True,
    ) -> None:
        self.client = KatanaClient(transport)
        self.transport = transport
        self.model = model
        self.period = 1.0 / poll_rate
        self.calibrate_on_start = calibrate_on_start
        self.collision_detection = collision_detection
        self.reconnect_period = reconnect_period
        self.calibration_timeout = calibration_timeout
        self.auto_setup = auto_setup
        self.status_every = max(1, status_every)
        self.on_state = on_state
        self._log_fn = log
        self.limit_margin = int(limit_margin)
        self.speed_limits = [int(v) for v in speed_limits]
        self.acceleration_limits = [int(a) for a in acceleration_limits]
        if len(self.speed_limits) != 6 or len(self.acceleration_limits) != 6:
            raise ValueError("speed_limits and acceleration_limits need one value per motor")
        self.connected = False
        self.calibrated = False
        self.setup_problem = ""  # why the last set-up stopped ('' when it passed)
        self.identification = ""
        self.master_version: tuple[int, int] | None = None
        #: why the connected controller is not driven at all ('' when it is): KNI's version check
        self.controller_refusal = ""
        self.link_error = "not connected yet"
        self.collision_message = ""
        self.polls = 0
        self.link_losses = 0
        self.connect_attempts = 0  # connection attempts ended (either way), for wait_connection
        self._calibrated_once = False
        self._freeze_on_connect = False
        self._jobs: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._cond = threading.Condition()
        self._state: ArmState | None = None
        self._status = [p.STATUS_INVALID] * 6
        self._unknown_statuses: set[int] = set()  # status values logged as unknown
        self._status_stamp = 0.0
        self._status_commands = -1  # client.motion_commands when _status was read
        #: (client.motion_commands, motor 6's encoder) of the last poll that read the fingers
        #: after a status read found them at rest, with nothing commanded in between
        self._gripper_rest: tuple[int, int] | None = None
        #: the move buffers hold nothing once every arm motor reports done in a status read
        #: after this monotonic time; None: unknown (a flush is owed before the next trajectory)
        self._queue_empty_after: float | None = None
        self._queue_empty_splines = -1  # client.spline_commands when that was set
        self._stream: Stream | None = None
        self._busy = 0
        self._busy_lock = threading.Lock()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Start the thread: it connects (retrying every reconnect_period) and polls."""
        if self._thread is not None and self._thread.is_alive():
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="katana-arm-worker", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 3.0) -> None:
        """End the thread and close the link (jobs still queued fail); start() opens it again."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=timeout)
        self.transport.close()
        self.connected = False

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def wait_connection(self, timeout: float) -> bool:
        """Wait (bounded) until the link is up or the next connection attempt has failed;
        whether it is up."""
        deadline = time.monotonic() + timeout
        with self._cond:
            attempts = self.connect_attempts
            while not self.connected and self.connect_attempts == attempts:
                remaining = deadline - time.monotonic()
                if remaining <= 0.0 or self._stop.is_set():
                    break
                self._cond.wait(min(remaining, 0.1))
        return self.connected

    def set_up(self) -> Future:
        """Run the set-up (limits, calibration probe, calibration when needed, collision
        detection) in the worker thread; the Future is done when it has ended (``ready`` and
        ``setup_problem`` say how). For ``auto_setup`` false: the lifecycle's activate."""
        return self.submit(lambda _client: self._set_up_now())

    def _set_up_now(self) -> None:
        if self.controller_refusal:
            return  # refused at the connection (its setup_problem says why): no command
        try:
            self._setup()
        except p.ControllerError as exc:
            self._setup_refused(exc)

    def _log(self, level: str, message: str) -> None:
        if self._log_fn is not None:
            try:
                self._log_fn(level, message)
            except Exception:  # noqa: BLE001 - a logging failure must not stop the worker
                pass

    # ------------------------------------------------------------------ state for callers
    @property
    def ready(self) -> bool:
        """Connected, set up, calibrated, and a state has been read: goals can run."""
        return (self.connected and self.calibrated and not self.setup_problem
                and self._state is not None)

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
            future.set_exception(NotConnected(self.not_connected_message()))
            return future
        self._jobs.put((fn, future))
        return future

    def call(self, fn: Callable[[KatanaClient], T], timeout: float = 5.0) -> T:
        """submit() and wait; raises the job's exception or TimeoutError."""
        return self.submit(fn).result(timeout=timeout)

    def not_connected_message(self) -> str:
        """Why jobs fail now: no link, and why."""
        return f"no connection to the Katana controller ({self.link_error})"

    def owe_freeze(self) -> None:
        """Freeze the arm first thing on the next connection (a freeze that could not be sent)."""
        self._freeze_on_connect = True

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
            return self._open_link()
        finally:
            with self._cond:
                self.connect_attempts += 1
                self._cond.notify_all()

    def _open_link(self) -> bool:
        self._queue_emptied(None)  # a controller met again may hold anything
        try:
            self.transport.open()
            self.client.echo()
            self.identification = self.client.identification()
            self.master_version = self.client.master_version()
        except (TransportError, p.ControllerError) as exc:
            self.transport.close()
            message = str(exc)
            if message != self.link_error:
                self._log("error", f"cannot reach the Katana controller: {message}; retrying")
            self.link_error = message
            return False
        version = ".".join(str(v) for v in self.master_version)
        self._log("info", f"connected to {self.transport.name}: '{self.identification}', "
                          f"master firmware version {version}")
        if "EMULATOR" in self.identification.upper():
            self._log("warn", "the controller is the katana-emulator, not a real arm")
        refused = self.master_version[0] > KNI_MAX_450_MASTER_VERSION
        self.controller_refusal = ""
        if refused:  # KNI exits here ("Incompatible Config File"): send it no command at all
            self.controller_refusal = self.setup_problem = (
                f"set-up refused: master version {self.master_version[0]} is above "
                f"{KNI_MAX_450_MASTER_VERSION}, and KNI refuses such a controller as a Katana "
                "400/450 (docs/hardware.md, first power-on checklist)")
            self._log("error", f"{self.setup_problem}; no command is sent and goals are refused")
        try:
            self._poll(force_status=True)
            if not refused:
                self._set_up_after_connect()
        except TransportError as exc:
            self.transport.close()
            self.link_error = f"set-up failed: {exc}"
            self._log("error", self.link_error)
            return False
        self.connected = True
        self.link_error = ""
        return True

    def _set_up_after_connect(self) -> None:
        if self._freeze_on_connect:  # lost mid-motion: stop what the buffer may still play
            try:
                self._freeze(self.client)
                self._log("warn", "reconnected: froze the arm (the link was lost)")
            except p.ControllerError as exc:
                self._log("error", f"reconnected: could not freeze the arm: {exc}")
        if self.auto_setup:
            self._set_up_now()
        else:  # set_up() decides; until then the calibration is not known
            self.calibrated = False
            self.setup_problem = ""

    def _setup(self) -> None:
        self.setup_problem = ""
        self._send_limits()
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
            self._keep_inside()
        self.client.collision_detection(self.collision_detection)

    def _setup_refused(self, exc: p.ControllerError) -> None:
        """A command refused during set-up: freeze the arm, report, refuse goals with it."""
        self.setup_problem = f"set-up stopped: {exc}"
        self._log("error", f"{self.setup_problem}; the arm is frozen and goals are refused "
                           "until a new set-up passes (restart the driver, or activate it "
                           "again)")
        try:
            self._freeze(self.client)
        except p.ControllerError as again:
            self._log("error", f"could not freeze the arm after the refusal: {again}")

    def _send_limits(self) -> None:
        """Speed and acceleration limits of motors 1..6 (S 3 and S 4, one request each), as the
        ROS 1 node's start-up sets them through KNI (setMotorVelocityLimit and
        setMotorAccelerationLimit for every motor)."""
        for motor in range(1, 7):
            self.client.set_speed_limit(motor, self.speed_limits[motor - 1])
            self.client.set_acceleration_limit(motor, self.acceleration_limits[motor - 1])

    def _probe_calibrated(self) -> bool:
        """Whether the controller still holds its calibration: it refuses moves until it is
        calibrated, and keeps its calibration while it stays powered, so a reconnection or a
        driver restart does not calibrate a calibrated arm again. The probe moves the gripper
        motor to where it is (clamped into the margin); a refusal (0xC0) or a failure reply
        (success byte 0) means not calibrated. A motor a collision stopped refuses every move,
        so such motors are held where they are first (as the ROS 1 node unblocks before its
        own probe): a collision is not taken for a lost calibration."""
        if p.STATUS_COLLISION in self._status[:6]:
            encoders = self.client.read_positions()
            pairs = zip(self._status[:6], encoders, strict=True)
            for motor, (status, enc) in enumerate(pairs, start=1):
                if status == p.STATUS_COLLISION:
                    try:
                        self.client.hold_motor(motor, enc)
                    except p.ControllerError as exc:
                        self._log("warn", f"could not unblock motor {motor}: {exc}")
            self._read_status()
        enc = self.client.read_positions()[5]
        lo, hi = self.model.safe_range(6, self.limit_margin)
        try:
            self.client.move_motor(6, min(max(enc, lo), hi))
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
        """Move every motor off its calibration stop to limit_margin (and a little more)
        encoders inside its range; the gripper opens (clamped into the margin)."""
        targets = self.model.backed_off_stops(self.limit_margin + CALIBRATION_BACKOFF_SLACK_ENC)
        lo, hi = self.model.safe_range(6, self.limit_margin)
        opened = int(round(self.model.gripper_angle_to_encoder(GRIPPER_OPEN_RAD)))
        targets.append(min(max(opened, lo), hi))
        self._move_and_wait(dict(enumerate(targets, start=1)), "back off their calibration stops")

    def _keep_inside(self) -> None:
        """Move the motors found within limit_margin of their limits (a calibrated arm that
        was not backed off: KNI's own calibration leaves every motor on its stop) to the margin
        and a little more inside, so that every target from here on can keep the margin."""
        encoders = self.client.read_positions()
        inner = self.limit_margin + CALIBRATION_BACKOFF_SLACK_ENC
        targets = {}
        for motor, enc in enumerate(encoders, start=1):
            lo, hi = self.model.safe_range(motor, self.limit_margin)
            if not lo <= enc <= hi:
                low, high = self.model.safe_range(motor, inner)
                targets[motor] = min(max(enc, low), high)
        if targets:
            self._log("info", f"motors {sorted(targets)} are within limit_margin_encoders "
                              f"({self.limit_margin}) of a limit: moving them inside")
            self._move_and_wait(targets, "move inside the limit margin")

    def _move_and_wait(self, targets: dict[int, int], what: str) -> None:
        """Move each motor to its target (C flag 24) and wait until all are there (10 s)."""
        for motor, enc in targets.items():
            try:
                self.client.move_motor(motor, enc)
            except NoReply:  # an absolute target: if lost, the state read below shows it
                pass
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and not self._stop.is_set():
            self._stop.wait(0.1)
            self._poll(force_status=True)
            encoders = self._state.encoders
            late = [m for m, t in targets.items() if abs(encoders[m - 1] - t) > 2]
            if not late:
                return
            for motor in late:
                if self._status[motor - 1] == p.STATUS_HOLDING:  # known not taken
                    self.client.move_motor(motor, targets[motor])
        raise TransportError(f"the motors did not {what} in 10 s")

    def _poll(self, force_status: bool = False) -> None:
        # Motor 6 at rest in the last status read, and nothing commanded since: the positions
        # read now hold its final place (_resting_gripper_encoder).
        gripper_rested = (self._status_commands == self.client.motion_commands
                          and self._status[5] in p.REST_STATUSES)
        encoders = self.client.read_positions()
        now = time.monotonic()
        self.polls += 1
        self._gripper_rest = (self.client.motion_commands, encoders[5]) if gripper_rested else None
        with self._busy_lock:
            busy = self._busy > 0
        if force_status or busy or self._stream is not None or self.polls % self.status_every == 0:
            self._read_status()
            for value in set(self._status) - p.KNOWN_STATUSES - self._unknown_statuses:
                self._unknown_statuses.add(value)
                self._log("warn", f"a motor reports status {value}, unknown to the driver "
                                  f"(motors 1..6: {self._status}); docs/hardware.md, first "
                                  "power-on checklist")
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

    def _read_status(self) -> list[int]:
        """Read the status flags; they, their stamp and the motion commands sent before them
        are kept (``_status``, ``_status_stamp``, ``_status_commands``)."""
        self._status_commands = self.client.motion_commands
        self._status = self.client.read_status()
        self._status_stamp = time.monotonic()
        return self._status

    def _on_collision(self) -> None:
        self._queue_emptied(None)  # stopped mid-trajectory: segments may be left
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
        self._flush(client)
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
