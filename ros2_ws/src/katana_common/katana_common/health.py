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
