"""katana_common.executor: rclpy's MultiThreadedExecutor without its two busy loops, and with
done-callbacks that only wake a waiting thread run at once.

Each test fills the thread pool with tasks that wait for a release, so that what comes next
stays queued, then counts how often the spinning thread goes round its wait loop meanwhile
(every round asks `can_execute` of every entity). rclpy's executor is measured the same way,
so each test also shows the loop it closes."""

from __future__ import annotations

import collections
import threading
import time

import pytest
import rclpy
from katana_common.executor import MultiThreadedExecutor, runs_inline
from katana_common.futures import wait_for_future
from rclpy.context import Context
from rclpy.event_handler import EventHandler
from rclpy.executors import MultiThreadedExecutor as RclpyMultiThreadedExecutor
from rclpy.task import Future
from std_msgs.msg import Int32

WORKERS = 2
WINDOW_S = 0.4  # how long the counted work stays queued
SPIN_SLICE_S = 0.1


def counting(base: type) -> type:
    class Counting(base):
        def __init__(self, *args, **kwargs) -> None:
            super().__init__(*args, **kwargs)
            self.rounds = 0  # rounds of the wait loop (one can_execute of a QoS event handler)
            self.handed_out: collections.Counter = collections.Counter()
            self._first_handler: EventHandler | None = None

        def can_execute(self, entity) -> bool:
            if isinstance(entity, EventHandler):
                self._first_handler = self._first_handler or entity
                self.rounds += entity is self._first_handler
            return super().can_execute(entity)

        def wait_for_ready_callbacks(self, *args, **kwargs):
            handler, entity, node = super().wait_for_ready_callbacks(*args, **kwargs)
            self.handed_out[id(handler)] += 1
            return handler, entity, node

    return Counting


class Graph:
    """A node with one subscription, spun in slices by `executor_type` with WORKERS threads."""

    def __init__(self, executor_type: type) -> None:
        self.context = Context()
        rclpy.init(context=self.context)
        self.executor = executor_type(num_threads=WORKERS, context=self.context)
        self.node = rclpy.create_node("executor_probe", context=self.context)
        self.received: list[int] = []
        self.node.create_subscription(Int32, "numbers", lambda m: self.received.append(m.data), 10)
        self.publisher = self.node.create_publisher(Int32, "numbers", 10)
        self.executor.add_node(self.node)
        self.release = threading.Event()
        self.busy = threading.Semaphore(0)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=SPIN_SLICE_S)

    def occupy_every_worker(self) -> None:
        def hold() -> None:
            self.busy.release()
            self.release.wait(10.0)

        for _ in range(WORKERS):
            self.executor.create_task(hold)
        for _ in range(WORKERS):
            assert self.busy.acquire(timeout=5.0), "a worker never started"

    def rounds_during(self, action) -> int:
        action()
        before = self.executor.rounds
        time.sleep(WINDOW_S)  # the work stays queued for this long: nothing to poll for
        return self.executor.rounds - before

    def close(self) -> None:
        self.release.set()
        self._stop.set()
        self._thread.join(timeout=5.0)
        self.executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture(params=[MultiThreadedExecutor, RclpyMultiThreadedExecutor],
                ids=["katana_common", "rclpy"])
def graph(request):
    g = Graph(counting(request.param))
    g.ours = request.param is MultiThreadedExecutor
    yield g
    g.close()


def test_a_queued_message_does_not_spin_the_waiting_thread(graph):
    graph.occupy_every_worker()
    rounds = graph.rounds_during(lambda: graph.publisher.publish(Int32(data=7)))
    if graph.ours:
        # a wait of SPIN_SLICE_S per round, plus a few wakes for the publish itself
        assert rounds <= WINDOW_S / SPIN_SLICE_S + 8
    else:  # the subscription's QoS event handlers see the pending sample and wake every wait
        assert rounds > 100
    graph.release.set()
    deadline = time.monotonic() + 5.0
    while not graph.received and time.monotonic() < deadline:
        time.sleep(0.01)
    assert graph.received == [7]  # and the message is delivered once a worker is free


def test_a_queued_task_is_handed_out_once(graph):
    graph.occupy_every_worker()
    ran = threading.Event()
    task = None

    def queue_task() -> None:
        nonlocal task
        task = graph.executor.create_task(ran.set)

    rounds = graph.rounds_during(queue_task)
    handed_out = graph.executor.handed_out[id(task)]
    if graph.ours:
        assert handed_out == 1
        assert rounds <= WINDOW_S / SPIN_SLICE_S + 8
    else:  # rclpy#1452: handed out and queued again on every round of the wait loop
        assert handed_out >= 2
    graph.release.set()
    assert ran.wait(5.0)
    assert task.done()


def test_a_thread_waiting_for_an_answer_is_woken_by_the_thread_that_answers(graph):
    """A future's done-callbacks are tasks of its executor in rclpy: with every worker busy, a
    thread waiting for the answer (wait_for_future) is not woken until a worker is free. Ours
    runs a callback marked runs_inline in the thread that completes the future; an unmarked
    one is still a task."""
    graph.occupy_every_worker()
    answer, other = Future(executor=graph.executor), Future(executor=graph.executor)
    woke, other_ran = threading.Event(), threading.Event()
    answer.add_done_callback(runs_inline(lambda _f: woke.set()))
    other.add_done_callback(lambda _f: other_ran.set())
    answer.set_result(42)
    other.set_result(7)
    if graph.ours:
        assert woke.is_set()  # before set_result returned
        assert wait_for_future(answer, 1.0, "answer") == 42
    else:
        assert not woke.wait(WINDOW_S)  # queued behind the busy workers
    assert not other_ran.wait(WINDOW_S)  # unmarked: a task, on either executor
    graph.release.set()
    assert woke.wait(5.0) and other_ran.wait(5.0)
