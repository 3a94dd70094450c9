"""Shared fixtures of the whole-graph tests (every node in one process, own Context per test)."""

import os

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")

import pytest  # noqa: E402


@pytest.fixture
def ros_graph():
    """An InProcessGraph (katana_bringup.testing): own Context, a MultiThreadedExecutor spinning
    in the background, bounded waits. Closed after the test."""
    from katana_bringup.testing import InProcessGraph

    graph = InProcessGraph()
    try:
        yield graph
    finally:
        graph.close()
