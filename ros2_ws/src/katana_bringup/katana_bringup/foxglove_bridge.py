"""foxglove_bridge: the graph's topics live in the Foxglove app (katana-run --foxglove [PORT]).

A thin node over katana_bringup.live_view: it advertises the forwarded topics (the recorder's,
the debug image, /diagnostics, /tf, /tf_static, robot_description) as their publishers
appear; while a client watches one, it subscribes to it with raw=True and a QoS its publishers
match (transient local where they all latch, best effort where any is) and hands the bytes to
the Foxglove server, which sends them to the app as CDR with the type's ros2msg schema.
Messages are stamped with their receive time on the node's clock (sim time with use_sim_time),
as the recorder stamps them.
"""

from __future__ import annotations

import importlib
import sys

from katana_common.node_runner import run_node
from katana_common.param_spec import Param
from katana_common.params import ParameterError, declare_parameters
from katana_common.qos import EVENT_QOS, SENSOR_QOS, STATE_QOS
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy

from .live_view import (
    DEFAULT_HOST,
    DEFAULT_PORT,
    LiveView,
    PublisherQos,
    forwarded_topics,
    subscription_kind,
)
from .recorder_node import TOPICS as RECORDED

NAME = "foxglove_bridge"
PARAMS = (
    Param("host", DEFAULT_HOST, "Address the Foxglove WebSocket server listens on (read-only; "
          "127.0.0.1: this machine only).", nonempty=True),
    Param("port", DEFAULT_PORT, "TCP port of the Foxglove WebSocket server (read-only; 0: any "
          "free port).", 0, 65535),
    Param("discovery_period_s", 0.5, "How often new topics are looked for, wall seconds "
          "(read-only).", 0.05, 60.0),
)
_QOS = {"sensor": SENSOR_QOS, "state": STATE_QOS, "event": EVENT_QOS}


def message_class(type_name: str):
    """The Python class of 'pkg/msg/Type'."""
    pkg, _, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


class FoxgloveBridgeNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__(NAME, **kwargs)
        self.params = declare_parameters(self, PARAMS)
        host, port = self.params["host"], self.params["port"]
        # a client's (un)subscribe, on the server's thread, wakes the executor to follow it
        self._wake = self.create_guard_condition(self.update)
        try:
            self.view = LiveView(host, port, on_change=self._wake.trigger)
        except OSError as err:  # the port is taken, or the host is not this machine's
            raise ParameterError(f"parameters 'host', 'port': {err}") from None
        self.wanted = forwarded_topics((t[0] for t in RECORDED), self.get_namespace())
        self._found: dict[str, tuple[type, str]] = {}  # topic -> (message class, QoS purpose)
        self._forwarding: dict[str, object] = {}
        self._refused: set[str] = set()
        self.get_logger().info(f"Foxglove live view on {self.view.url}")
        # wall time: topics are found even before the sim's first /clock
        self.create_timer(self.params["discovery_period_s"], self.update,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.update()

    @property
    def url(self) -> str:
        return self.view.url

    def update(self) -> None:
        """Advertise the forwarded topics that appeared; subscribe to the watched ones, and
        unsubscribe from those no client watches any more."""
        self._discover()
        watched = self.view.watchers.topics()
        for topic, (cls, kind) in self._found.items():
            if topic in watched and topic not in self._forwarding:
                self._forwarding[topic] = self.create_subscription(
                    cls, topic, self._forward(topic), _QOS[kind], raw=True)
            elif topic not in watched and topic in self._forwarding:
                self.destroy_subscription(self._forwarding.pop(topic))

    def _discover(self) -> None:
        for topic, types in self.get_topic_names_and_types():
            if topic not in self.wanted or topic in self._found or topic in self._refused:
                continue
            kind = subscription_kind(
                PublisherQos(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE,
                             i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL)
                for i in self.get_publishers_info_by_topic(topic))
            if kind is None:
                continue  # only subscribers so far
            if len(types) != 1:
                self._refuse(topic, f"published with {len(types)} types ({', '.join(types)})")
                continue
            try:
                cls = message_class(types[0])
                self.view.add_topic(topic, types[0])
            except (ImportError, AttributeError, LookupError, OSError, ValueError) as err:
                self._refuse(topic, str(err))
                continue
            self._found[topic] = (cls, kind)

    def _refuse(self, topic: str, why: str) -> None:
        self._refused.add(topic)
        self.get_logger().warn(f"{topic} is not forwarded to Foxglove: {why}")

    def _forward(self, topic: str):
        def on_message(data: bytes) -> None:
            self.view.log(topic, data, self.get_clock().now().nanoseconds)
        return on_message

    def stop(self) -> None:
        """Close the server (run_node and katana-run call this)."""
        self.view.close()

    def destroy_node(self) -> None:
        if hasattr(self, "view"):
            self.view.close()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return run_node(FoxgloveBridgeNode, NAME, args)


if __name__ == "__main__":
    sys.exit(main())
