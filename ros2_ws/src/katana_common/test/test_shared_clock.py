"""katana_common.shared_clock: the nodes of one process on simulated time follow /clock from one
subscription, and use_sim_time still switches each of them as rclpy's TimeSource does."""

from __future__ import annotations

import os
import time

import pytest
import rclpy
from katana_common.executor import BackgroundSpin, MultiThreadedExecutor
from katana_common.qos import CLOCK_QOS
from katana_common.shared_clock import CLOCK_TOPIC, SharedClock
from katana_common.testing import wait_until
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.time import Time
from rosgraph_msgs.msg import Clock

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")

WALL_TIME_AFTER_NS = 10**18  # 2001-09-09: a clock past this is on wall time, not on /clock


class Graph:
    """Three nodes on simulated time, one on wall time, a /clock publisher; spun in the
    background."""

    def __init__(self) -> None:
        self.context = Context()
        rclpy.init(context=self.context)
        self.executor = MultiThreadedExecutor(num_threads=4, context=self.context)
        sim = [Parameter("use_sim_time", Parameter.Type.BOOL, True)]
        self.sim_nodes = [Node(f"clock_probe_{i}", context=self.context, parameter_overrides=sim)
                          for i in range(3)]
        self.wall_node = Node("clock_probe_wall", context=self.context)
        self.talker = Node("clock_talker", context=self.context)
        self.publisher = self.talker.create_publisher(Clock, CLOCK_TOPIC, CLOCK_QOS)
        self.nodes = [*self.sim_nodes, self.wall_node, self.talker]
        for node in self.nodes:
            self.executor.add_node(node)
        self.spin = BackgroundSpin(self.executor)

    def clock_subscriptions(self) -> int:
        return sum(1 for node in self.nodes for sub in node.subscriptions
                   if sub.topic_name == CLOCK_TOPIC)

    def publish_until(self, seconds: int, nodes: list[Node]) -> bool:
        """Publish /clock at `seconds` until every one of `nodes` reads it (best effort: one
        message may be lost)."""
        def arrived() -> bool:
            self.publisher.publish(Clock(clock=Time(seconds=seconds).to_msg()))
            return all(n.get_clock().now().nanoseconds == seconds * 10**9 for n in nodes)
        return bool(wait_until(arrived, 5.0, 0.02))

    def close(self) -> None:
        self.spin.stop()
        self.executor.shutdown(timeout_sec=2.0)
        for node in self.nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def graph():
    g = Graph()
    yield g
    g.close()


def test_every_joined_node_follows_clock_from_one_subscription(graph):
    assert graph.clock_subscriptions() == 3  # rclpy's: one per node on simulated time
    shared = SharedClock()
    assert [shared.join(n) for n in graph.sim_nodes] == [True, True, True]
    assert not shared.join(graph.wall_node)  # wall time: nothing to share
    assert shared.host is graph.sim_nodes[0]
    assert graph.clock_subscriptions() == 1
    assert graph.publish_until(5, graph.sim_nodes)
    assert graph.publish_until(7, graph.sim_nodes)
    assert graph.wall_node.get_clock().now().nanoseconds > WALL_TIME_AFTER_NS


def test_use_sim_time_still_switches_each_joined_node(graph):
    shared = SharedClock()
    for node in graph.sim_nodes:
        shared.join(node)
    host, other, third = graph.sim_nodes
    # the host off simulated time: its clock is on wall time, the others still follow /clock
    host.set_parameters([Parameter("use_sim_time", Parameter.Type.BOOL, False)])
    assert graph.publish_until(11, [other, third])
    assert host.get_clock().now().nanoseconds > WALL_TIME_AFTER_NS
    # another node off and on again: rclpy gives it its own subscription, and it follows
    other.set_parameters([Parameter("use_sim_time", Parameter.Type.BOOL, False)])
    assert other.get_clock().now().nanoseconds > WALL_TIME_AFTER_NS
    other.set_parameters([Parameter("use_sim_time", Parameter.Type.BOOL, True)])
    assert graph.clock_subscriptions() == 2
    assert graph.publish_until(13, [other, third])
    # and the host back on simulated time follows too
    host.set_parameters([Parameter("use_sim_time", Parameter.Type.BOOL, True)])
    assert graph.publish_until(17, graph.sim_nodes)
    time.sleep(0.05)
    assert all(n.get_clock().now().nanoseconds == 17 * 10**9 for n in graph.sim_nodes)
