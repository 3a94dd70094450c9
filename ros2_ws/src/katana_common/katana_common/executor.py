"""rclpy's MultiThreadedExecutor without two ways its spinning thread loops while it waits.

While the spinning thread loops it holds the GIL, which the worker it is waiting for needs to
start. In bench_arm's graph (one process) a result reached its client 100-600 ms after its
goal ended in about one goal of three, and a pick-and-place took 0.6-0.9 s where 0.27 s does.

1. A subscription's QoS event handlers (rclpy gives each subscription two: incompatible QoS
   and incompatible type) wait on the subscription's DDS reader. Once a message has arrived
   and its callback is queued, the subscription leaves the wait set until a worker takes the
   message, but its event handlers stay in it, and the reader's pending message ends every
   wait at once with no event ready: a busy loop. Here the event handlers leave with it.
2. rclpy#1452: `wait_for_ready_callbacks` hands out every task that is neither done nor
   executing, and this executor only queues for its pool what it is handed: until a worker
   starts a task, the task is handed out and queued again in every round of the wait loop (in
   the busy loop of 1., up to 700 times). Fixed in rclpy 10.0.4 (rolling, rclpy#1547), not in
   the Jazzy wheels on PyPI. Here a task counts as executing from the moment it is queued; the
   worker clears the mark just before it runs the task.

A future's done-callbacks are executor tasks in rclpy (the executor that completed the future
queues them): a thread waiting for an answer is woken only after one more round of the wait
loop and a worker. `runs_inline(callback)` marks a callback that only wakes a waiting thread
(sets an Event); this executor runs such a callback at once, in the thread that completed the
future. Every other callback, and every callback on another executor, runs as before.

Use it wherever a multi-threaded executor is made. `BackgroundSpin` spins an executor in a
thread of its own, for a graph that the calling thread only waits on (in-process graphs, tests).
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from rclpy.event_handler import EventHandler
from rclpy.executors import Executor
from rclpy.executors import MultiThreadedExecutor as _RclpyMultiThreadedExecutor
from rclpy.task import Future, Task

_INLINE = "_katana_runs_inline"


def runs_inline(callback: Callable) -> Callable:
    """Mark `callback` (quick, thread-safe, never raising: it sets an Event) to be run at once
    by this module's executor when a future completes, instead of as a task."""
    setattr(callback, _INLINE, True)
    return callback


def _start(task: Task) -> None:
    task._executing = False  # rclpy's Task runs only when it is not marked executing
    task()


class _QueuedCountsAsExecuting:
    """The executor's thread pool; what it queues reports executing until a worker takes it."""

    def __init__(self, pool: ThreadPoolExecutor) -> None:
        self._pool = pool

    def submit(self, task: Task) -> Any:
        task._executing = True
        return self._pool.submit(_start, task)

    def __getattr__(self, name: str) -> Any:  # shutdown and the rest: the pool's own
        return getattr(self._pool, name)


class MultiThreadedExecutor(_RclpyMultiThreadedExecutor):
    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._executor = _QueuedCountsAsExecuting(self._executor)
        # event handler -> its subscription (None: a publisher's); only the spinning thread uses it
        self._subscription_of: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()

    def create_task(self, callback: Callable, *args: Any, **kwargs: Any) -> Task | Future:
        """A callback marked `runs_inline` runs now (the returned future is done); any other
        becomes a task, as in rclpy."""
        if getattr(callback, _INLINE, False):
            callback(*args, **kwargs)
            done: Future = Future()
            done.set_result(None)
            return done
        return super().create_task(callback, *args, **kwargs)

    def can_execute(self, entity: Any) -> bool:
        if not super().can_execute(entity):
            return False
        if not isinstance(entity, EventHandler):
            return True
        if entity not in self._subscription_of:  # a handler not seen yet: map them all again
            for node in self.get_nodes():
                for subscription in node.subscriptions:
                    for handler in subscription.event_handlers:
                        self._subscription_of[handler] = weakref.ref(subscription)
            self._subscription_of.setdefault(entity, None)
        owner = self._subscription_of[entity]
        subscription = owner() if owner is not None else None
        return subscription is None or not subscription._executor_event


class BackgroundSpin:
    """Spins `executor` in a daemon thread until `stop()` or until its context shuts down.

    spin_once in slices of `slice_s`, not spin(): the thread leaves its loop within a slice of
    `stop()`, so the executor can then be shut down and the nodes destroyed without a handle
    going away under the spinning thread (the order node_runner.spin_nodes keeps too)."""

    def __init__(self, executor: Executor, slice_s: float = 0.05) -> None:
        self.executor, self.slice_s = executor, slice_s
        self._leave = threading.Event()
        self._thread = threading.Thread(target=self._spin, name="background spin", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._leave.is_set() and self.executor.context.ok():
            self.executor.spin_once(timeout_sec=self.slice_s)

    def stop(self, timeout_s: float = 5.0) -> None:
        """Leave the loop and wait (at most `timeout_s`) for the thread to end."""
        self._leave.set()
        self._thread.join(timeout=timeout_s)
