"""The bounded wait on an rclpy future, from a callback thread of a multi-threaded executor.

rclpy's `spin_until_future_complete` must not be called from inside a callback of an executor
that is already spinning; there the done-callback and an Event are the way to wait (the
project's executor runs that callback at once: katana_common.executor.runs_inline). The wait
also ends early when the node is stopping, so shutdown never hangs on a reply that will not
come.
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

