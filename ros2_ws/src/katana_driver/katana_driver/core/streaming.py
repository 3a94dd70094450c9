"""Streaming a trajectory into the controller's move buffer: the half of the arm worker
(core.arm.ArmWorker) that feeds a SplinePlan to the controller a little ahead of time.

Segments are never re-sent. When a segment's reply is lost (transport.NoReply) the stream
stops sending and reads the controller's status when that segment should be playing: motors
moving means it was taken (go on), motors done means it was not (the arm has stopped at the
end of the previous segment: the stream ends with an error and the goal is aborted). Before
the motion starts, a lost reply is resolved by flushing the move buffers (harmless twice) and
streaming again from the first segment.

Once the arm moves, a segment goes out only after a status read that came after the previous
one, and not while a motor reports its move buffer full (152, KNI's MSF_LINMOV "moving poly,
polymb full"): KNI waits that out before it sends a segment (lmBase.cpp, CLMBase::movLM2P
polls the motors until none reports 152). A buffer that stays full for BUFFER_FULL_TIMEOUT_S
ends the stream with an error (the goal is aborted and the arm frozen).

A trajectory starts with a flush of the move buffers only when they are not known empty (the
first after a connection, and any after a trajectory that did not play to its end, a
collision or a restart); the fingers' hold segment takes the last poll's position when that
poll found motor 6 at rest and nothing was commanded since. After a finished goal both save a
request each (40 ms on the arm).
"""

from __future__ import annotations

import time
from concurrent.futures import Future
from dataclasses import dataclass, field

from . import protocol as p
from .client import KatanaClient
from .splines import SplinePlan, hold_segment
from .transport import NoReply

START_BUFFER_TICKS = 40  # queue this much motion before starting (as the ROS 1 driver did)
LOOKAHEAD_S = 1.5  # keep segments starting within this horizon in the move buffer
MAX_IN_BUFFER = 12  # of the assumed 16-segment move buffer
CONFIRM_MARGIN_S = 0.06  # read the status this long after an unconfirmed segment should start
MAX_RESTARTS = 3  # re-streams (after a flush) of a trajectory that has not started moving
START_SLACK_ENC = 5  # encoders a motor may be from the plan's start for a re-stream
#: a full move buffer frees a slot when its playing segment ends (at most 0.5 s, the longest
#: segment): full for this long means the controller no longer plays it
BUFFER_FULL_TIMEOUT_S = 3.0
STATUS_REFRESH_S = 0.04  # while the buffer is full, read the status at most this often


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
    last_sent_at: float = 0.0  # monotonic time of the last segment sent
    full_since: float | None = None  # when a motor was first seen reporting a full buffer

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


class TrajectoryStreaming:
    """ArmWorker's streaming, run in its thread. The worker provides ``client``, ``state``,
    ``submit``, ``_log``, ``_stream`` (the running Stream or None), ``_state`` (the last
    poll), ``_read_status`` and what it keeps (``_status``, ``_status_stamp``,
    ``_status_commands``), ``_gripper_rest``, ``_queue_empty_after``, ``_queue_empty_splines``
    and ``collision_message``."""

    def start_trajectory(self, plan: SplinePlan) -> Stream:
        """Begin streaming ``plan``; ``stream.started`` resolves when the arm was told to go."""
        state = self.state
        gripper = state.encoders[5] if state is not None else 0
        stream = Stream(plan=plan, gripper_enc=gripper)
        future = self.submit(lambda client: self._begin_stream(client, stream))
        future.add_done_callback(lambda f: _forward_error(f, stream))
        return stream

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
            self._read_status()
        # Motor 6 rides along in every H row as a hold segment: hold it where it is now. The
        # last poll's position serves only when that poll found it at rest and nothing was
        # commanded since (a position cached before a finishing gripper move made the fingers
        # jump back); otherwise it is read.
        gripper = self._resting_gripper_encoder()
        # Flushed unless known empty: neither KNI nor the ROS 1 node flushes before a
        # trajectory, and after one played to its end the buffers hold nothing.
        if not self._queue_known_empty():
            self._flush(client)
        stream.gripper_enc = client.read_positions()[5] if gripper is None else gripper
        self._stream = stream
        try:
            self._stream_step()
        except p.ControllerError as exc:
            self._end_stream(RuntimeError(f"the controller refused the trajectory: {exc}"))

    def _flush(self, client: KatanaClient) -> None:
        """Empty the move buffers (``C 0 32``; harmless twice)."""
        client.flush_buffers()
        self._queue_emptied(time.monotonic())

    def _queue_known_empty(self) -> bool:
        """The move buffers hold nothing: since a flush, or the end of a trajectory whose every
        segment the controller took, no spline command went out, and a status read after it
        found every arm motor done (holding or spline finished: the trajectory judge's "at
        rest")."""
        after = self._queue_empty_after
        return (after is not None and self._queue_empty_splines == self.client.spline_commands
                and self._status_stamp > after
                and all(s in p.REST_STATUSES for s in self._status[:5]))

    def _queue_emptied(self, after: float | None) -> None:
        """The move buffers hold nothing once the arm motors are done after ``after`` (None:
        unknown, flush before the next trajectory)."""
        self._queue_empty_after = after
        self._queue_empty_splines = self.client.spline_commands

    def _resting_gripper_encoder(self) -> int | None:
        """Motor 6's encoder from the last poll, when the status read before it found motor 6
        at rest and no motion command went out since; else None."""
        rest = self._gripper_rest
        if rest is None or rest[0] != self.client.motion_commands:
            return None
        return rest[1]

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
                if not self._buffer_has_room(stream):
                    return
            if i == n - 1:
                activity = p.ACTIVITY_LAST
            elif stream.started_at is None and plan.start_ticks[i + 1] < START_BUFFER_TICKS:
                activity = p.ACTIVITY_QUEUE
            else:
                activity = p.ACTIVITY_START
            row = plan.segments[i]
            gripper = hold_segment(stream.gripper_enc, row[0].duration)
            sent_at = stream.last_sent_at = time.monotonic()
            try:
                self.client.send_spline_all([*row, gripper], activity)
            except NoReply as exc:
                begins = max(stream.queue_end, sent_at) if stream.started_at else sent_at
                stream.unconfirmed = (i, activity, sent_at, begins + CONFIRM_MARGIN_S)
                self._log("warn", f"segment {i}: {exc}; reading the controller's state")
                return
            self._taken(stream, i, activity, sent_at)
            if stream.started_at is not None:
                break  # one segment per turn once moving, so that polls are never starved
        if stream.sent >= n:
            self._end_stream(None)

    def _buffer_has_room(self, stream: Stream) -> bool:
        """False while a motor reports its move buffer full (152), from a status read after
        the last segment went out; ends the stream when that lasts BUFFER_FULL_TIMEOUT_S."""
        full = p.STATUS_BUFFER_FULL in self._status[:6]
        now = time.monotonic()
        if self._status_stamp <= stream.last_sent_at or (
            full and now - self._status_stamp >= STATUS_REFRESH_S
        ):
            self._read_status()
            full = p.STATUS_BUFFER_FULL in self._status[:6]
        if not full:
            stream.full_since = None
            return True
        if stream.full_since is None:
            stream.full_since = now
            self._log("debug", "the controller's move buffer is full (152): waiting")
        elif now - stream.full_since > BUFFER_FULL_TIMEOUT_S:
            motors = [i + 1 for i, st in enumerate(self._status[:6]) if st == p.STATUS_BUFFER_FULL]
            self._end_stream(RuntimeError(
                f"the controller's move buffer stayed full (status 152 on motors {motors}) for "
                f"{BUFFER_FULL_TIMEOUT_S:g} s; stopped the trajectory"))
        return False

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
        status = self._read_status()  # answered after the segment: the link is in order
        encoders = self.client.read_positions()
        stream.unconfirmed = None
        row = stream.plan.segments[i]
        at_end = all(abs(e - seg.target) <= START_SLACK_ENC
                     for e, seg in zip(encoders, row, strict=False))
        moved = any(seg.target != seg.p0 for seg in row)
        # Moving (16, 24 or 152): it plays (nothing else is queued after it). Done at its end
        # (a late answer to the status read): it played. Done where it starts: the queue ran
        # dry without it.
        if all(s in p.MOVING_STATUSES for s in status[:5]) or (at_end and moved):
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
        self._flush(self.client)
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
        played_out = (error is None and not stream.cancelled and stream.unconfirmed is None
                      and stream.sent >= len(stream.plan.segments))
        self._queue_emptied(stream.queue_end if played_out else None)
        for future in (stream.started, stream.finished_sending):
            if not future.done():
                if error is None:
                    future.set_result(stream.started_at)
                else:
                    future.set_exception(error)


def _forward_error(future: Future, stream: Stream) -> None:
    exc = future.exception()
    if exc is not None:
        for f in (stream.started, stream.finished_sending):
            if not f.done():
                f.set_exception(exc)
