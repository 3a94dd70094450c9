"""katana_bringup.live_view without ROS: which topics are forwarded, the QoS a subscription
needs, the topic -> channel table, who watches what, the command line's address, and the
Foxglove server itself over loopback, read by an independent WebSocket client."""

from __future__ import annotations

import argparse
import socket
import sys
from pathlib import Path

import pytest
from katana_bringup.live_view import (
    DEFAULT_HOST,
    DEFAULT_PORT,
    EXTRA_TOPICS,
    SUBPROTOCOL,
    ChannelTable,
    LiveView,
    PublisherQos,
    Watchers,
    absolute_name,
    add_foxglove_arguments,
    forwarded_topics,
    foxglove_address,
    subscription_kind,
)
from katana_bringup.recording import message_definition
from katana_common.cli_args import listen_host, tcp_port
from katana_common.testing import wait_until

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib
from foxglove_ws_client import FoxgloveClient, MessageFrame  # noqa: E402


def test_relative_names_are_put_under_the_namespace_and_absolute_ones_kept():
    assert absolute_name("camera/image_raw") == "/camera/image_raw"
    assert absolute_name("camera/image_raw", "/arm1") == "/arm1/camera/image_raw"
    assert absolute_name("camera/image_raw", "/arm1/") == "/arm1/camera/image_raw"
    assert absolute_name("/diagnostics", "/arm1") == "/diagnostics"


def test_the_forwarded_topics_are_the_recorded_ones_and_the_extra_ones():
    topics = forwarded_topics(["joint_states", "curiosity/learner_state"], "/k")
    assert topics == {"/k/joint_states", "/k/curiosity/learner_state",
                      "/k/perception/debug_image", "/diagnostics", "/tf", "/tf_static",
                      "/k/robot_description"}
    assert len(EXTRA_TOPICS) == 5


@pytest.mark.parametrize("publishers,kind", [
    ([], None),
    ([PublisherQos(reliable=False, transient_local=False)], "sensor"),
    ([PublisherQos(True, True), PublisherQos(False, True)], "sensor"),  # one best effort
    ([PublisherQos(True, True)], "state"),
    ([PublisherQos(True, True), PublisherQos(True, True)], "state"),
    ([PublisherQos(True, True), PublisherQos(True, False)], "event"),  # one volatile
    ([PublisherQos(True, False)], "event"),
])
def test_the_subscription_matches_every_publisher(publishers, kind):
    assert subscription_kind(publishers) == kind


def test_a_topic_gets_one_channel_with_the_schema_of_its_type():
    made = []
    table = ChannelTable(lambda *a: made.append(a) or len(made),
                         definition=lambda t: f"text of {t}\n")
    first = table.add("/a", "pkg/msg/A")
    assert table.add("/a", "pkg/msg/A") == first  # made once
    table.add("/b", "pkg/msg/A")
    assert made == [("/a", "pkg/msg/A", "text of pkg/msg/A\n"),
                    ("/b", "pkg/msg/A", "text of pkg/msg/A\n")]
    assert table.get("/a") == first and table.get("/c") is None
    assert table.types() == {"/a": "pkg/msg/A", "/b": "pkg/msg/A"}
    with pytest.raises(ValueError, match="/a is forwarded as pkg/msg/A, not pkg/msg/B"):
        table.add("/a", "pkg/msg/B")
    assert len(made) == 2


def test_a_type_without_a_definition_makes_no_channel():
    def definition(type_name: str) -> str:
        raise LookupError(type_name)

    table = ChannelTable(lambda *a: a, definition=definition)
    with pytest.raises(LookupError):
        table.add("/a", "nowhere/msg/X")
    assert table.types() == {}


def test_watchers_report_the_first_and_the_last_client_of_a_topic():
    changes = []
    w = Watchers(lambda: changes.append(sorted(w.topics())))
    w.subscribe(1, "/a")
    w.subscribe(2, "/a")  # a second client: nothing changes
    w.subscribe(1, "/b")
    w.unsubscribe(1, "/a")  # client 2 still watches
    assert w.topics() == {"/a", "/b"}
    w.unsubscribe(2, "/a")
    w.unsubscribe(2, "/a")  # twice (a disconnect after an unsubscribe): once reported
    w.unsubscribe(3, "/c")  # never subscribed
    assert changes == [["/a"], ["/a", "/b"], ["/b"]]


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="p", exit_on_error=False)
    add_foxglove_arguments(parser, tcp_port, listen_host)
    return parser


@pytest.mark.parametrize("argv,address", [
    ([], None),
    (["--foxglove"], (DEFAULT_HOST, DEFAULT_PORT)),
    (["--foxglove", "9000"], (DEFAULT_HOST, 9000)),
    (["--foxglove", "0"], (DEFAULT_HOST, 0)),
    (["--foxglove-host", "localhost"], ("localhost", DEFAULT_PORT)),
    (["--foxglove", "9001", "--foxglove-host", "::1"], ("::1", 9001)),
])
def test_the_options_give_the_address_of_the_live_view(argv, address):
    assert foxglove_address(_parser().parse_args(argv)) == address
    assert (DEFAULT_HOST, DEFAULT_PORT) == ("127.0.0.1", 8765)


@pytest.mark.parametrize("argv", [["--foxglove", "65536"], ["--foxglove", "-1"],
                                  ["--foxglove", "http"], ["--foxglove-host", ""]])
def test_a_bad_port_or_host_is_refused_while_parsing(argv):
    with pytest.raises(argparse.ArgumentError):
        _parser().parse_args(argv)


# -- the server over loopback --------------------------------------------------------------
TYPE = "sensor_msgs/msg/JointState"


def test_a_client_sees_the_channel_with_the_recorders_schema_and_gets_the_bytes_logged():
    view = LiveView("127.0.0.1", 0)
    try:
        assert view.port > 0 and view.url == f"ws://127.0.0.1:{view.port}"
        view.add_topic("/joint_states", TYPE)
        # an app offers both names of the protocol; the server takes its own
        with FoxgloveClient(view.port, subprotocol=f"foxglove.websocket.v1, {SUBPROTOCOL}") as c:
            assert c.subprotocol == SUBPROTOCOL
            channel = c.wait_for_channels({"/joint_states"})["/joint_states"]
            assert channel["encoding"] == "cdr"
            assert channel["schemaEncoding"] == "ros2msg"
            assert channel["schemaName"] == TYPE
            assert channel["schema"] == message_definition(TYPE)  # what an MCAP file holds
            view.log("/joint_states", b"nobody watches", 1)  # dropped: no subscriber
            assert view.watchers.topics() == frozenset()
            subs = c.subscribe({"/joint_states": channel})
            assert wait_until(lambda: view.watchers.topics() == {"/joint_states"})
            view.log("/joint_states", b"\x00\x01\x00\x00payload", 1234567890123)
            frame = c.next_event()
            while not isinstance(frame, MessageFrame):  # status ops may come first
                frame = c.next_event()
            assert subs[frame.subscription] == "/joint_states"
            assert frame.log_time_ns == 1234567890123
            assert frame.payload == b"\x00\x01\x00\x00payload"
            c.send_op("unsubscribe", subscriptionIds=list(subs))
            assert wait_until(lambda: not view.watchers.topics())
    finally:
        view.close()


def test_a_client_offering_only_the_old_protocol_name_is_refused():
    view = LiveView("127.0.0.1", 0)
    try:
        with pytest.raises(ConnectionError, match="400"):
            FoxgloveClient(view.port, subprotocol="foxglove.websocket.v1")
    finally:
        view.close()


def test_a_port_in_use_is_an_os_error_naming_the_address():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(OSError, match=f"cannot listen on 127.0.0.1:{port}"):
            LiveView("127.0.0.1", port)
