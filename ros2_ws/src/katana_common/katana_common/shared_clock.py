"""One /clock subscription for every node of a process that runs on simulated time.

rclpy gives each node with use_sim_time its own TimeSource, and each TimeSource its own
subscription to /clock. In a process that spins a whole graph (katana-run, katana-demo, the
in-process graphs of katana-robot) every /clock message then becomes a callback per node: in
the fast-sim loop's graph about 80 of the 210 callbacks an experiment costs the executor, in
a process whose threads share one GIL with the physics.

`SharedClock.join(node)` drops the node's own /clock subscription and hands each /clock
message to the node's TimeSource (its `clock_callback`, as the subscription would) from one
subscription on the first node joined, in a callback group of its own (a node busy in a long
callback does not hold the others' clocks back). What rclpy's TimeSource does otherwise is
unchanged: setting a joined node's use_sim_time to false puts its clock on wall time, and
setting it back to true gives it its own subscription again (a second source of the same
times). A node on wall time is not joined.

The node's TimeSource is rclpy's private `_time_source` (and its `_clock_sub`): rclpy has no
public way to share one. Where they are missing (another rclpy) `join` leaves the node as it is.
"""

from __future__ import annotations

import weakref

from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from rosgraph_msgs.msg import Clock

from .qos import CLOCK_QOS

CLOCK_TOPIC = "/clock"


class SharedClock:
    """Drives the clocks of the nodes joined from one /clock subscription."""

    def __init__(self) -> None:
        self._sources: list[weakref.ref] = []  # the joined nodes' TimeSources
        self._host: weakref.ref | None = None
        self._subscription = None

    @property
    def host(self) -> Node | None:
        """The node that holds the shared subscription (the first joined), if any."""
        return self._host() if self._host is not None else None

    def join(self, node: Node) -> bool:
        """Drive `node`'s clock from the shared subscription instead of its own; False (and
        nothing changed) when the node has no /clock subscription (it runs on wall time)."""
        source = getattr(node, "_time_source", None)
        own = getattr(source, "_clock_sub", None)
        if own is None:
            return False
        if self._subscription is None:
            self._host = weakref.ref(node)
            self._subscription = node.create_subscription(
                Clock, CLOCK_TOPIC, self._on_clock, CLOCK_QOS,
                callback_group=MutuallyExclusiveCallbackGroup())
        node.destroy_subscription(own)
        source._clock_sub = None  # as rclpy leaves it when it destroys the subscription itself
        self._sources.append(weakref.ref(source))
        return True

    def _on_clock(self, msg: Clock) -> None:
        for ref in self._sources:
            source = ref()
            if source is not None:
                source.clock_callback(msg)
