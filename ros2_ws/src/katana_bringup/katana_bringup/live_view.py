"""A live view of the graph in Foxglove without a ROS install (ROS-free: no rclpy here).

The Foxglove app decodes ROS 2 messages itself when a channel says "cdr" and carries a
"ros2msg" schema (the .msg text followed by every type it uses, as rosbag2's MCAP files hold
it). So the bridge forwards the bytes a raw subscription receives, never deserialized, and
needs no per-type code: `LiveView` is a foxglove-sdk WebSocket server with one channel per
topic; `katana_bringup.foxglove_bridge` is the thin node that feeds it. A topic is advertised as
soon as it is published, but subscribed to only while a client watches it (`Watchers`): an
image nobody looks at is not copied, and perception draws its debug image only while the
topic has a subscriber.

What is forwarded: the recorder's topics (the ones that show a run), plus what a viewer
wants live that a recording leaves out: the perception debug image, /diagnostics, and /tf,
/tf_static and robot_description where a full install publishes them.
"""

from __future__ import annotations

import argparse
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Generic, TypeVar

import foxglove
from foxglove.websocket import ChannelView, Client, ServerListener

from .recording import message_definition

#: the address Foxglove connects to by default (the app's own default is ws://localhost:8765)
DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
#: the WebSocket subprotocol foxglove-sdk's server accepts: the Foxglove WebSocket protocol
#: under its current name (the same messages as "foxglove.websocket.v1", which it refuses); the
#: Foxglove app and Lichtblick since late 2025 offer it
SUBPROTOCOL = "foxglove.sdk.v1"
#: forwarded besides the recorder's topics (absent ones are simply never discovered)
EXTRA_TOPICS = ("perception/debug_image", "/diagnostics", "/tf", "/tf_static",
                "robot_description")


def absolute_name(topic: str, namespace: str = "/") -> str:
    """`topic` under `namespace` as the graph lists it ('camera/image_raw' in '/a' is
    '/a/camera/image_raw'); an absolute name stays as it is."""
    if topic.startswith("/"):
        return topic
    return f"{namespace.rstrip('/')}/{topic}"


def forwarded_topics(recorded: Iterable[str], namespace: str = "/",
                     extra: Iterable[str] = EXTRA_TOPICS) -> frozenset[str]:
    """The absolute names the bridge forwards: the recorder's and the extra ones."""
    return frozenset(absolute_name(t, namespace) for t in (*recorded, *extra))


@dataclass(frozen=True)
class PublisherQos:
    """What a subscriber must match of one publisher's QoS."""

    reliable: bool
    transient_local: bool


def subscription_kind(publishers: Iterable[PublisherQos]) -> str | None:
    """The katana_common.qos purpose a subscription matching every publisher has: "sensor"
    (best effort) if any publisher is best effort (a reliable subscription would get nothing
    from it), "state" (transient local: the last message a late joiner needs) if every one is
    transient local, else "event" (reliable, volatile). None without publishers."""
    publishers = list(publishers)
    if not publishers:
        return None
    if not all(p.reliable for p in publishers):
        return "sensor"
    if all(p.transient_local for p in publishers):
        return "state"
    return "event"


C = TypeVar("C")


class ChannelTable(Generic[C]):
    """topic -> its channel, made once per topic with the type's ros2msg schema.

    `make(topic, schema_name, schema_text)` builds a channel; `definition(type)` gives the
    schema text (recording.message_definition: the same text a recording's MCAP schema has).
    A topic seen with another type later keeps its first channel: a channel's schema is fixed.
    """

    def __init__(self, make: Callable[[str, str, str], C],
                 definition: Callable[[str], str] = message_definition) -> None:
        self._make = make
        self._definition = definition
        self._channels: dict[str, tuple[str, C]] = {}
        self._lock = threading.Lock()

    def add(self, topic: str, type_name: str) -> C:
        """The channel of `topic`, made on the first call. Raises ValueError if the topic has
        a channel of another type, and what `definition` raises for a type without a .msg."""
        with self._lock:
            if topic in self._channels:
                known, channel = self._channels[topic]
                if known != type_name:
                    raise ValueError(f"{topic} is forwarded as {known}, not {type_name}")
                return channel
            channel = self._make(topic, type_name, self._definition(type_name))
            self._channels[topic] = (type_name, channel)
            return channel

    def get(self, topic: str) -> C | None:
        entry = self._channels.get(topic)
        return None if entry is None else entry[1]

    def types(self) -> dict[str, str]:
        """topic -> type name of every channel made."""
        return {topic: type_name for topic, (type_name, _) in self._channels.items()}


class Watchers:
    """Which clients watch which topic. `on_change()` is called (from the server's thread)
    when a topic gains its first watcher or loses its last one."""

    def __init__(self, on_change: Callable[[], object] = lambda: None) -> None:
        self._clients: dict[str, set[int]] = {}
        self._lock = threading.Lock()
        self.on_change = on_change

    def subscribe(self, client: int, topic: str) -> None:
        with self._lock:
            clients = self._clients.setdefault(topic, set())
            first = not clients
            clients.add(client)
        if first:
            self.on_change()

    def unsubscribe(self, client: int, topic: str) -> None:
        with self._lock:
            clients = self._clients.get(topic, set())
            had = bool(clients)
            clients.discard(client)
            last = had and not clients
        if last:
            self.on_change()

    def topics(self) -> frozenset[str]:
        """The topics at least one client watches."""
        with self._lock:
            return frozenset(t for t, clients in self._clients.items() if clients)


class _Listener(ServerListener):
    """The server's subscribe and unsubscribe events (a disconnect unsubscribes) to Watchers."""

    def __init__(self, watchers: Watchers) -> None:
        self.watchers = watchers

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        self.watchers.subscribe(client.id, channel.topic)

    def on_unsubscribe(self, client: Client, channel: ChannelView) -> None:
        self.watchers.unsubscribe(client.id, channel.topic)


class LiveView:
    """A Foxglove WebSocket server on `host`:`port` (0: any free port) with one "cdr" channel
    per topic. It has its own foxglove Context, so two views in one process (tests) never
    share channels. `watchers` says which topics clients watch; `on_change` is called when
    that changes. Raises OSError when the address cannot be listened on."""

    def __init__(self, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
                 name: str = "katana", definition: Callable[[str], str] = message_definition,
                 on_change: Callable[[], object] = lambda: None) -> None:
        self._context = foxglove.Context()
        self.watchers = Watchers(on_change)
        try:
            self._server = foxglove.start_server(
                name=name, host=host, port=port, context=self._context,
                server_listener=_Listener(self.watchers))
        except RuntimeError as err:  # FoxgloveError: "Failed to bind port: ..."
            raise OSError(f"cannot listen on {host}:{port}: {err}") from None
        self.host = host
        self.port = self._server.port
        self.channels: ChannelTable[foxglove.Channel] = ChannelTable(self._channel, definition)
        self._closed = False

    @property
    def url(self) -> str:
        """The address to give the Foxglove app ("Open connection", Foxglove WebSocket)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    def _channel(self, topic: str, type_name: str, schema_text: str) -> foxglove.Channel:
        schema = foxglove.Schema(name=type_name, encoding="ros2msg",
                                 data=schema_text.encode())
        return foxglove.Channel(topic, schema=schema, message_encoding="cdr",
                                context=self._context)

    def add_topic(self, topic: str, type_name: str) -> None:
        """Advertise `topic` to every client (and to those that connect later)."""
        self.channels.add(topic, type_name)

    def log(self, topic: str, data: bytes, log_time_ns: int) -> None:
        """Send one serialized message to the clients subscribed to `topic` (none: nothing is
        copied)."""
        channel = self.channels.get(topic)
        if channel is not None and not self._closed and channel.has_sinks():
            channel.log(data, log_time=log_time_ns)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._server.stop()


# -- command line (katana-run, katana-demo) ---------------------------------------------------
def add_foxglove_arguments(parser: argparse.ArgumentParser, port_type: Callable[[str], int],
                           host_type: Callable[[str], str]) -> None:
    """--foxglove [PORT] and --foxglove-host HOST, each checked while parsing by the given
    types (katana_common.cli_args.tcp_port and listen_host)."""
    parser.add_argument("--foxglove", type=port_type, nargs="?", const=DEFAULT_PORT,
                        default=None, metavar="PORT",
                        help="serve a live view to the Foxglove app on a WebSocket (default "
                        f"port {DEFAULT_PORT}; 0: any free port)")
    parser.add_argument("--foxglove-host", type=host_type, default=None, metavar="HOST",
                        help=f"address the Foxglove server listens on (default {DEFAULT_HOST}, "
                        "this machine only; implies --foxglove)")


def foxglove_address(args: argparse.Namespace) -> tuple[str, int] | None:
    """(host, port) of the live view the options ask for, or None."""
    port, host = getattr(args, "foxglove", None), getattr(args, "foxglove_host", None)
    if port is None and host is None:
        return None
    return (host or DEFAULT_HOST, DEFAULT_PORT if port is None else port)
