"""What the tests share: bounded waits (`spin_until` spins an executor, `wait_until` polls while
something else spins; `call_service` calls a service with them), and for tests that start node
processes a ROS domain of their own, a probe node, and `stop_process` (signal a node process,
time how long it takes to exit)."""

from __future__ import annotations

import os
import re
import select
import signal
import subprocess
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TypeVar

import rclpy
from rclpy.context import Context
from rclpy.executors import Executor, SingleThreadedExecutor
from rclpy.node import Node

T = TypeVar("T")


def spin_until(executor: Executor, condition: Callable[[], T], timeout_s: float = 10.0,
               slice_s: float = 0.05) -> T:
    """Spin `executor` (slices of at most `slice_s`, never past the deadline) until
    `condition()` is truthy; returns that value, or the last (falsy) one after `timeout_s`.
    For a test that spins its graph itself: `assert spin_until(ex, client.server_is_ready)`."""
    return _until(condition, timeout_s, lambda s: executor.spin_once(timeout_sec=s), slice_s)


class AnswerLost(TimeoutError):
    """The service took the request but no answer came: rmw_fastrtps drops a response while it
    has not matched the client's response reader ("failed to send response (timeout)" in the
    server's log), likely on a loaded machine right after the client appeared."""


def call_service(executor: Executor, client, request, timeout_s: float = 10.0,
                 answer_timeout_s: float | None = None):
    """Call `client`'s service with `request` and return the response, spinning `executor`
    while waiting (at most `timeout_s` for the service, and `answer_timeout_s`, by default as
    long, for the answer). TimeoutError when the service did not appear; AnswerLost (a
    TimeoutError, the request forgotten) when the answer did not come."""
    if not spin_until(executor, client.service_is_ready, timeout_s):
        raise TimeoutError(f"service {client.srv_name} not available within {timeout_s} s")
    future = client.call_async(request)
    wait_s = timeout_s if answer_timeout_s is None else answer_timeout_s
    if not spin_until(executor, future.done, wait_s):
        client.remove_pending_request(future)
        raise AnswerLost(f"no answer from {client.srv_name} within {wait_s} s")
    return future.result()


def wait_until(condition: Callable[[], T], timeout_s: float = 10.0, poll_s: float = 0.005) -> T:
    """Poll `condition()` every `poll_s` until it is truthy; returns that value, or the last
    (falsy) one after `timeout_s`. For a graph another thread spins, or no ROS at all."""
    return _until(condition, timeout_s, time.sleep, poll_s)


def _until(condition: Callable[[], T], timeout_s: float, pause: Callable[[float], object],
           step_s: float) -> T:
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        remaining = deadline - time.monotonic()
        if value or remaining <= 0.0:
            return value
        pause(min(step_s, remaining))


def wait_for_output(stream, pattern: str, timeout_s: float) -> re.Match | None:
    """The first match of `pattern` in what a child process writes to `stream` (its pipe),
    within `timeout_s`; None at the end of the stream or the time. Reads the pipe's descriptor
    itself: select() on the buffered file object misses lines that arrived in one chunk with an
    earlier one (readline took them into its buffer, and the descriptor has nothing more)."""
    fd, seen = stream.fileno(), b""
    deadline = time.monotonic() + timeout_s
    while (remaining := deadline - time.monotonic()) > 0:
        if not select.select([fd], [], [], min(remaining, 0.5))[0]:
            continue
        chunk = os.read(fd, 65536)
        if not chunk:
            return None
        seen += chunk
        found = re.search(pattern, seen.decode("utf-8", errors="replace"))
        if found:
            return found
    return None


def stop_process(proc: subprocess.Popen, sig: int, timeout_s: float = 30.0,
                 dump_s: float = 5.0) -> tuple[float, str | None, str | None]:
    """Send `sig` to `proc` and wait up to `timeout_s` for it to exit. A process still running
    then gets SIGABRT, so that its stacks show why (every process that spins nodes prints them
    on SIGABRT, katana_common.node_runner), and SIGKILL `dump_s` later if it is still there (a
    stuck node never outlives its test). Returns the seconds from the signal to the exit (or
    to the timeout) and the process's stdout and stderr (None where they were not piped). A process
    ended this way has a negative returncode, for the caller's assertions."""
    start = time.monotonic()
    proc.send_signal(sig)
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        seconds = time.monotonic() - start
        proc.send_signal(signal.SIGABRT)
        try:
            proc.wait(timeout=dump_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    else:
        seconds = time.monotonic() - start
    out, err = proc.communicate()
    return seconds, out, err


def private_domain_id() -> int:
    """A ROS domain for this test process's node processes, distinct between the workers of one
    `pytest -n` run (PYTEST_XDIST_WORKER gwN), so that two tests never see each other's graph."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if worker.startswith("gw") and worker[2:].isdigit():
        return 120 + (int(worker[2:]) % 2) * 50 + os.getpid() % 45  # room for a few more
    return 120 + os.getpid() % 100


def private_ros_env(**extra: str) -> dict[str, str]:
    """os.environ with a private domain and localhost-only discovery, for a node subprocess."""
    return dict(os.environ, ROS_DOMAIN_ID=str(private_domain_id()),
                ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", **extra)


def use_private_domain(monkeypatch) -> None:
    """Put this process (rclpy.init reads it) and the node processes it starts on the private
    domain, for one test (pytest's monkeypatch restores the environment after it)."""
    monkeypatch.setenv("ROS_DOMAIN_ID", str(private_domain_id()))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


@contextmanager
def probe_node(name: str) -> Iterator[tuple[Node, SingleThreadedExecutor]]:
    """A node of the test process in a Context of its own, with an executor the test spins."""
    context = Context()
    rclpy.init(context=context)
    node = Node(name, context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        yield node, executor
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
