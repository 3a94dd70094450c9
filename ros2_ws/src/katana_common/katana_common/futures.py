"""The bounded wait on an rclpy future, from a callback thread of a multi-threaded executor.

rclpy's `spin_until_future_complete` must not be called from inside a callback of an executor
that is already spinning; there the done-callback and an Event are the way to wait (the
project's executor runs that callback at once: katana_common.executor.runs_inline). The wait
also ends early when the node is stopping, so shutdown never hangs on a reply that will not
come. And the bounded wait for an item of a numbered stream (`NumberedArrivals`).
"""

from __future__ import annotations

import threading
from typing import Any

from .executor import runs_inline


class Stopped(RuntimeError):
    """The wait ended because the node is shutting down."""


def wait_for_future(
    future: Any,
    timeout_s: float,
    what: str,
    stop: threading.Event | None = None,
    poll_s: float = 0.05,
) -> Any:
    """Return `future.result()`; TimeoutError after `timeout_s`, Stopped when `stop` is set.

    On a time-out or stop the future is cancelled, so a late answer is dropped.
    """
    done = threading.Event()
    future.add_done_callback(runs_inline(lambda _f: done.set()))
    remaining = float(timeout_s)
    while not done.is_set():
        if stop is not None and stop.is_set():
            future.cancel()
            raise Stopped(f"{what}: stopped while waiting")
        if remaining <= 0.0:
            future.cancel()
            raise TimeoutError(f"{what}: no answer within {timeout_s:.1f} s")
        step = min(poll_s if stop is not None else remaining, remaining)
        done.wait(step)
        remaining -= step
    return future.result()


class NumberedArrivals:
    """The number of the latest item of a numbered stream (a BlockArray's `sequence`), and a
    bounded wait for a given number or a later one. A service asked to answer "from item n or
    a later one" waits here until its own subscription has taken n in: answering from the one
    before would depend on thread timing."""

    def __init__(self) -> None:
        self._arrived = threading.Condition()
        self.number = 0

    def arrived(self, number: int) -> None:
        with self._arrived:
            self.number = int(number)
            self._arrived.notify_all()

    def wait_for(self, number: int, timeout_s: float) -> bool:
        """Whether item `number` (or a later one) is in, waiting at most `timeout_s`."""
        with self._arrived:
            return self._arrived.wait_for(lambda: self.number >= number, timeout_s)
