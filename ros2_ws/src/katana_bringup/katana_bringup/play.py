"""katana-play: a recording back on the ROS graph (the ROS side of katana_bringup.playback).

`PlayerNode` makes one publisher per played topic, of the recorded type, offering the QoS the
recorded publishers offered (bag_qos.playback_profile), and one on /clock
(rosgraph_msgs/Clock); `play()` publishes the recorded CDR bytes as they are. Nodes with
use_sim_time then see the recorded times.
"""

from __future__ import annotations

import importlib
import signal
import sys
import threading
import time
from pathlib import Path

import rclpy
from katana_common.qos import CLOCK_QOS
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rclpy.signals import SignalHandlerOptions
from rosgraph_msgs.msg import Clock

from . import bag_qos, playback
from .recording import repair


def message_class(type_name: str) -> type:
    """The Python class of 'pkg/msg/Type' (the package must be installed)."""
    pkg, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)


def rclpy_qos(profile: dict) -> QoSProfile:
    """A bag_qos playback profile as rclpy's (system_default where rmw would not take it)."""
    def policy(enum, value: str):
        return enum[value.upper()] if value.upper() in enum.__members__ else \
            enum.SYSTEM_DEFAULT

    qos = QoSProfile(
        history=policy(HistoryPolicy, profile["history"]), depth=profile["depth"],
        reliability=policy(ReliabilityPolicy, profile["reliability"]),
        durability=policy(DurabilityPolicy, profile["durability"]),
        avoid_ros_namespace_conventions=profile["avoid_ros_namespace_conventions"])
    if qos.history == HistoryPolicy.UNKNOWN:
        qos.history = HistoryPolicy.KEEP_LAST
    liveliness = policy(LivelinessPolicy, profile["liveliness"])
    qos.liveliness = (LivelinessPolicy.SYSTEM_DEFAULT if liveliness == LivelinessPolicy.UNKNOWN
                      else liveliness)
    for key in ("deadline", "lifespan", "liveliness_lease_duration"):
        ns = bag_qos.duration_ns(profile[key])
        if 0 < ns < bag_qos.INFINITE_NS:  # 0 and infinite: the default, as rmw reads both
            setattr(qos, key, Duration(nanoseconds=ns))
    return qos


class PlayerNode(Node):
    """Publishers for a recording's topics; `play` sends its messages."""

    def __init__(self, path: str | Path, topics: list[str] | None = None,
                 **kwargs) -> None:
        super().__init__("katana_play", **kwargs)
        self.path = Path(path)
        recorded = playback.recorded_topics(self.path)
        self.topics = {n: t for n, t in recorded.items() if topics is None or n in topics}
        self.pubs = {name: self.create_publisher(message_class(t.type_name), name,
                                                 rclpy_qos(t.qos))
                     for name, t in self.topics.items()}
        self.clock_pub = self.create_publisher(Clock, "/clock", CLOCK_QOS)
        self.stop_event = threading.Event()

    def _publish_clock(self, ns: int) -> None:
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(ns, 1_000_000_000)
        self.clock_pub.publish(msg)

    def _wait_until(self, t: float) -> bool:
        while (left := t - time.monotonic()) > 0:
            if self.stop_event.wait(min(left, 0.05)):
                return False
        return not self.stop_event.is_set()

    def play(self, rate: float = 1.0, loop: bool = False, delay_s: float = 0.0) -> int:
        """Publish the recording at its timing / rate; returns how many messages."""
        return playback.play(
            lambda: playback.recorded_messages(self.path, list(self.topics)), rate, loop,
            lambda m: self.pubs[m.topic].publish(m.data), self._publish_clock,
            time.monotonic, self._wait_until, delay_s=delay_s)


def main(argv: list[str] | None = None) -> int:
    args = playback.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        report = repair(args.file)
    except Exception as err:  # the original file is left as it was
        print(f"katana-play: cannot repair {args.file}: {err}", file=sys.stderr)
        return 1
    if report.repaired:
        print(f"katana-play: {args.file} had no index (its recorder was killed); rewrote it "
              f"indexed with its {report.messages} complete messages", flush=True)
    elif args.repair:
        print(f"katana-play: {args.file} is already indexed ({report.messages} messages)")
    if args.repair:
        return 0
    rclpy.init(args=["katana-play"], signal_handler_options=SignalHandlerOptions.NO)
    node = PlayerNode(args.file, args.topics)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: node.stop_event.set())
    try:
        n = node.play(args.rate, args.loop, args.delay)
        print(f"katana-play: published {n} messages", flush=True)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
