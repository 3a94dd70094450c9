"""In-process ROS graphs for tests: an own rclpy Context, nodes spun by a MultiThreadedExecutor
in a background thread, and bounded waits on conditions (never a bare sleep)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import rclpy
from katana_common.executor import MultiThreadedExecutor
from rclpy.context import Context
from rclpy.node import Node


class InProcessGraph:
    """Usage: with InProcessGraph() as g: g.add(node...); g.wait_for(lambda: ...)."""

    def __init__(self, threads: int = 8) -> None:
        self.context = Context()
        rclpy.init(context=self.context)
        self.executor = MultiThreadedExecutor(num_threads=threads, context=self.context)
        self.nodes: list[Node] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set() and self.context.ok():
            self.executor.spin_once(timeout_sec=0.05)

    def add(self, *nodes: Node) -> None:
        for node in nodes:
            self.nodes.append(node)
            self.executor.add_node(node)

    def node(self, name: str) -> Node:
        """A plain helper node (for clients and subscriptions) in this graph."""
        n = Node(name, context=self.context)
        self.add(n)
        return n

    @staticmethod
    def wait_for(cond: Callable[[], Any], timeout: float = 10.0, poll: float = 0.005) -> Any:
        """Poll cond until it is truthy (returns its value) or fail after timeout seconds."""
        deadline = time.monotonic() + timeout
        while True:
            value = cond()
            if value:
                return value
            if time.monotonic() > deadline:
                raise TimeoutError(f"condition not met within {timeout} s")
            threading.Event().wait(poll)

    def result(self, future, timeout: float = 30.0):
        """Wait (bounded) for an rclpy future and return its result."""
        self.wait_for(future.done, timeout)
        return future.result()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self.executor.shutdown(timeout_sec=5.0)
        for node in self.nodes:
            self.executor.remove_node(node)
            node.destroy_node()
        self.nodes.clear()
        rclpy.try_shutdown(context=self.context)

    def __enter__(self) -> InProcessGraph:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
