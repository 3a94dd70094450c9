"""What tests that start node processes share: a ROS domain of their own, and a probe node."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node


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
