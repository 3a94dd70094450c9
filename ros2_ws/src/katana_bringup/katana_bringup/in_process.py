"""A ROS graph inside this process: an own rclpy Context (optionally in another ROS domain),
nodes spun by a MultiThreadedExecutor in a background thread (those on simulated time sharing
one /clock subscription, katana_common.shared_clock), and bounded waits on conditions
(never a bare sleep). katana-robot runs its truth measurement and skill trials in one, and
watches a run of another process through one; the whole-graph tests and benches use it too."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import rclpy
from katana_common.executor import BackgroundSpin, MultiThreadedExecutor
from katana_common.shared_clock import SharedClock
from katana_common.testing import wait_until
from rclpy.context import Context
from rclpy.node import Node


class InProcessGraph:
    """Usage: with InProcessGraph() as g: g.add(node...); g.wait_for(lambda: ...)."""

    def __init__(self, threads: int = 8, domain_id: int | None = None,
                 close_timeout_s: float = 5.0) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.close_timeout_s = close_timeout_s
        self.executor = MultiThreadedExecutor(num_threads=threads, context=self.context)
        self.nodes: list[Node] = []
        self._clock = SharedClock()
        self._spin = BackgroundSpin(self.executor)

    def add(self, *nodes: Node) -> None:
        for node in nodes:
            self.nodes.append(node)
            self._clock.join(node)
            self.executor.add_node(node)

    def node(self, name: str) -> Node:
        """A plain helper node (for clients and subscriptions) in this graph."""
        n = Node(name, context=self.context)
        self.add(n)
        return n

    @staticmethod
    def wait_for(cond: Callable[[], Any], timeout: float = 10.0, poll: float = 0.005) -> Any:
        """Poll cond until it is truthy (returns its value) or fail after timeout seconds."""
        value = wait_until(cond, timeout, poll)
        if not value:
            raise TimeoutError(f"condition not met within {timeout} s")
        return value

    def result(self, future, timeout: float = 30.0):
        """Wait (bounded) for an rclpy future and return its result."""
        self.wait_for(future.done, timeout)
        return future.result()

    def close(self) -> None:
        self._spin.stop(self.close_timeout_s)
        self.executor.shutdown(timeout_sec=self.close_timeout_s)
        for node in self.nodes:
            self.executor.remove_node(node)
            node.destroy_node()
        self.nodes.clear()
        rclpy.try_shutdown(context=self.context)

    def __enter__(self) -> InProcessGraph:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
