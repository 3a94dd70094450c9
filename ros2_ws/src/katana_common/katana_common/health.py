"""What a node says about its health, without ROS: a level, one line, and named values.

katana_common.diagnostics publishes these on /diagnostics (diagnostic_msgs); the nodes compute
them from their own state with the helpers here, so the rules are tested without a graph.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

#: diagnostic_msgs/DiagnosticStatus levels
OK, WARN, ERROR, STALE = 0, 1, 2, 3


@dataclass(frozen=True)
class Health:
    """One component's status: `level` (OK..STALE), `message` and `values` (shown as text)."""

    level: int
    message: str
    values: Mapping[str, object] = field(default_factory=dict)


class RateMeter:
    """Events per second over the last `window_s` seconds of a monotonic clock (wall time:
    what a person watching the run sees, whatever clock the node runs on)."""

    def __init__(self, window_s: float = 10.0,
                 now: Callable[[], float] = time.monotonic) -> None:
        if not window_s > 0.0:
            raise ValueError(f"window_s must be > 0, got {window_s}")
        self.window_s = float(window_s)
        self._now = now
        self._times: deque[float] = deque()
        self.started = now()
        self.count = 0
        self._last: float | None = None

    def tick(self) -> None:
        self._last = self._now()
        self._times.append(self._last)
        self.count += 1

    def _drop_old(self, now: float) -> None:
        while self._times and self._times[0] < now - self.window_s:
            self._times.popleft()

    def per_second(self) -> float:
        """Events in the window over the window (or over the time since the start, if that is
        shorter), so the first seconds are not under-counted."""
        now = self._now()
        self._drop_old(now)
        span = min(self.window_s, now - self.started)
        return len(self._times) / span if span > 0.0 else 0.0

    def age_s(self) -> float | None:
        """Seconds since the last event; None before the first."""
        return None if self._last is None else self._now() - self._last


def stream_health(what: str, meter: RateMeter, stale_after_s: float = 2.0) -> Health:
    """A stream's health (a camera's images): WARN before the first message and when none came
    for `stale_after_s` (wall time), else OK with its rate."""
    age = meter.age_s()
    values = {f"{what}_per_s": meter.per_second(), "received": meter.count,
              "last_age_s": age if age is not None else "never"}
    if age is None:
        return Health(WARN, f"no {what} yet", values)
    if age > stale_after_s:
        return Health(WARN, f"no {what} for {age:.1f} s", values)
    return Health(OK, f"{meter.per_second():.1f} {what}/s", values)


class ClockRatio:
    """How fast a clock runs against wall time over the last `window_s` wall seconds (a sim's
    real-time factor), from (wall, clock) samples taken when asked."""

    def __init__(self, clock: Callable[[], float], window_s: float = 10.0,
                 now: Callable[[], float] = time.monotonic) -> None:
        if not window_s > 0.0:
            raise ValueError(f"window_s must be > 0, got {window_s}")
        self.clock, self.window_s, self._now = clock, float(window_s), now
        self._samples: deque[tuple[float, float]] = deque()

    def ratio(self) -> float | None:
        """Clock seconds per wall second since the oldest sample in the window; None until two
        samples lie apart in wall time."""
        wall, clock = self._now(), self.clock()
        self._samples.append((wall, clock))
        while len(self._samples) > 2 and self._samples[1][0] <= wall - self.window_s:
            self._samples.popleft()
        first_wall, first_clock = self._samples[0]
        if wall <= first_wall:
            return None
        return (clock - first_clock) / (wall - first_wall)


def pace_health(ratio: float | None, target: float, sim_time_s: float) -> Health:
    """A simulation's pace: OK as fast as it can go (`target` 0) or within 10 % of its target
    real-time factor, WARN when it falls behind (the machine is too slow for the pace)."""
    values = {"real_time_factor": ratio if ratio is not None else "not measured yet",
              "target_real_time_factor": target if target > 0 else "as fast as possible",
              "sim_time_s": sim_time_s}
    if ratio is None:
        return Health(OK, "starting", values)
    if target > 0 and ratio < 0.9 * target:
        return Health(WARN, f"behind its pace: {ratio:.2f}x wall time, asked {target:g}x",
                      values)
    return Health(OK, f"{ratio:.2f}x wall time", values)
