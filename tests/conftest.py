"""Shared fixtures of the whole-graph tests (every node in one process, own Context per test)."""

import os

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")

import pytest  # noqa: E402
from katana_bringup.in_process import InProcessGraph  # noqa: E402
from rclpy.action import get_action_names_and_types  # noqa: E402

#: what a graph offers, by kind: name -> [type names]
LISTERS = {
    "topics": lambda node: dict(node.get_topic_names_and_types()),
    "actions": lambda node: dict(get_action_names_and_types(node)),
    "services": lambda node: dict(node.get_service_names_and_types()),
}


@pytest.fixture
def ros_graph():
    """An InProcessGraph (katana_bringup.in_process): own Context, a MultiThreadedExecutor
    spinning in the background, bounded waits. Closed after the test."""
    graph = InProcessGraph()
    try:
        yield graph
    finally:
        graph.close()


def _offers(graph: InProcessGraph, probe, kind: str, expected: dict[str, str]) -> None:
    def found():
        names = LISTERS[kind](probe)
        return expected.keys() <= names.keys() and names

    names = graph.wait_for(found)
    for name, type_name in expected.items():
        assert names[name] == [type_name], name


@pytest.fixture
def graph_offers():
    """graph_offers(g, probe, kind, {name: type}): wait (bounded) until the graph, seen from
    `probe`, offers every name of `kind` ("topics", "actions" or "services"), then check that
    each has its one type."""
    return _offers
