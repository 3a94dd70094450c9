"""Keep in-process ROS tests of this package off the network (before any rclpy.init), and the
graph they share: sim_node and a probe node, spun in the background."""

import os

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")

from contextlib import contextmanager  # noqa: E402

import pytest  # noqa: E402
import rclpy  # noqa: E402
from katana_common.executor import BackgroundSpin, MultiThreadedExecutor  # noqa: E402
from katana_sim.sim_node import SimNode  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402


@contextmanager
def _sim_graph(probe_name: str, **params):
    ctx = Context()
    rclpy.init(context=ctx)
    sim = SimNode(context=ctx, parameter_overrides=[
        Parameter(name, value=value) for name, value in params.items()])
    probe = Node(probe_name, context=ctx)
    executor = MultiThreadedExecutor(num_threads=6, context=ctx)
    executor.add_node(sim)
    executor.add_node(probe)
    spin = BackgroundSpin(executor)
    try:
        yield sim, probe
    finally:
        spin.stop()
        executor.shutdown(timeout_sec=5)
        sim.destroy_node()
        probe.destroy_node()
        rclpy.try_shutdown(context=ctx)


@pytest.fixture(scope="session")
def sim_graph():
    """`with sim_graph(probe_name, **sim_node_params) as (sim, probe):` sim_node with these
    parameters and a probe node in a Context of their own, spun in a background thread; torn
    down in order (the spinning ends, the executor shuts down, the nodes go) on leaving."""
    return _sim_graph
