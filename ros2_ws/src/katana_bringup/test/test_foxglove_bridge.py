"""foxglove_bridge in a graph: a WebSocket client on loopback sees the graph's topics
advertised with their ros2msg schemas, subscribes to three, and gets CDR payloads that decode,
with the advertised schema text and independently of ROS (rosbags), to the values published;
the bridge subscribes to a ROS topic only while a client watches it, and katana-run and
katana-demo refuse a bad --foxglove before any work."""

from __future__ import annotations

import math
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import rclpy
from katana_bringup import demo, run
from katana_bringup.foxglove_bridge import FoxgloveBridgeNode
from katana_bringup.in_process import InProcessGraph
from katana_common.params import ParameterError
from katana_common.qos import SENSOR_QOS, STATE_QOS
from katana_common.testing import private_ros_env, stop_process, wait_for_output
from katana_interfaces.msg import HeightModel, LearnerState
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from sensor_msgs.msg import CameraInfo, JointState

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib
from foxglove_ws_client import FoxgloveClient, MessageFrame  # noqa: E402

TOPICS = {"/joint_states": JointState, "/curiosity/learner_state": LearnerState,
          "/camera/camera_info": CameraInfo}


def _bridge(g: InProcessGraph, port: int = 0) -> FoxgloveBridgeNode:
    node = FoxgloveBridgeNode(context=g.context, parameter_overrides=[
        Parameter("host", value="127.0.0.1"), Parameter("port", value=port),
        Parameter("discovery_period_s", value=0.1)])
    g.add(node)
    return node


def _messages():
    joints = JointState(name=["katana_motor1_pan_joint", "katana_motor2_lift_joint"],
                        position=[0.25, -1.5], velocity=[0.0, 0.125])
    joints.header.frame_id = "katana_base_link"
    state = LearnerState(experiments=17, queries=11, plans=6, strategy="q1", alpha=0.5,
                         theta=0.1, all_known_at=-1, heights=[
                             HeightModel(height=0, examples=9, weights=[0.5] * 7,
                                         margins=[0.75, -0.25], confidence=[0.125, 0.5],
                                         unknown=[False, True]),
                             HeightModel(height=1, examples=2, weights=[], margins=[0.0],
                                         confidence=[1.0], unknown=[True])])
    info = CameraInfo(width=640, height=480, distortion_model="plumb_bob",
                      k=[500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0])
    info.header.frame_id = "camera_optical_frame"
    return {"/joint_states": joints, "/curiosity/learner_state": state,
            "/camera/camera_info": info}


def _decode_without_ros(channel: dict, payload: bytes):
    """The payload decoded by rosbags with only the schema the channel advertised."""
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(channel["schema"], channel["schemaName"]))
    return store.deserialize_cdr(payload, channel["schemaName"])


def test_a_client_gets_three_topics_that_decode_to_what_was_published():
    sent = _messages()
    with InProcessGraph() as g:
        bridge = _bridge(g)
        pub = g.node("foxglove_test_publisher")
        qos = {"/joint_states": 10, "/curiosity/learner_state": STATE_QOS,
               "/camera/camera_info": SENSOR_QOS}
        pubs = {t: pub.create_publisher(TOPICS[t], t, qos[t]) for t in TOPICS}
        # connect once the channels exist: foxglove-sdk 0.30.3 may refuse a subscription to a
        # channel made while the client was connecting ("unknown channel")
        g.wait_for(lambda: set(bridge.view.channels.types()) == set(TOPICS))
        with FoxgloveClient(bridge.view.port) as client:
            channels = client.wait_for_channels(set(TOPICS))
            for topic, cls in TOPICS.items():
                ch = channels[topic]
                assert (ch["encoding"], ch["schemaEncoding"]) == ("cdr", "ros2msg")
                assert ch["schemaName"] == cls.__module__.split(".")[0] + "/msg/" + cls.__name__
            assert not pubs["/joint_states"].get_subscription_count()  # nobody watches yet
            subs = client.subscribe({t: channels[t] for t in TOPICS})
            g.wait_for(lambda: all(p.get_subscription_count() for p in pubs.values()))
            received: dict[str, bytes] = {}
            for _ in range(300):  # bounded: publish until each topic has come through
                for topic, p in pubs.items():
                    if topic not in received:
                        p.publish(sent[topic])
                event = client.poll(0.1)
                while event is not None:
                    if isinstance(event, MessageFrame):
                        received.setdefault(subs[event.subscription], event.payload)
                    event = client.poll(0.0)
                if len(received) == len(TOPICS):
                    break
            assert set(received) == set(TOPICS)

    joints = deserialize_message(received["/joint_states"], JointState)
    assert list(joints.name) == ["katana_motor1_pan_joint", "katana_motor2_lift_joint"]
    assert list(joints.position) == [0.25, -1.5] and joints.header.frame_id == "katana_base_link"
    state = deserialize_message(received["/curiosity/learner_state"], LearnerState)
    assert (state.experiments, state.strategy, len(state.heights)) == (17, "q1", 2)
    assert list(state.heights[0].margins) == [0.75, -0.25]
    info = deserialize_message(received["/camera/camera_info"], CameraInfo)
    assert (info.width, info.height, info.k[2]) == (640, 480, 320.0)

    # the same bytes with nothing but the advertised schema text, as the Foxglove app does
    raw = _decode_without_ros(channels["/curiosity/learner_state"],
                              received["/curiosity/learner_state"])
    assert (raw.experiments, raw.queries, raw.plans, raw.all_known_at) == (17, 11, 6, -1)
    assert [h.height for h in raw.heights] == [0, 1]
    assert list(raw.heights[0].confidence) == [0.125, 0.5]
    assert list(raw.heights[0].unknown) == [False, True]
    raw_joints = _decode_without_ros(channels["/joint_states"], received["/joint_states"])
    assert list(raw_joints.name) == ["katana_motor1_pan_joint", "katana_motor2_lift_joint"]
    assert list(raw_joints.velocity) == [0.0, 0.125]
    raw_info = _decode_without_ros(channels["/camera/camera_info"], received["/camera/camera_info"])
    assert raw_info.distortion_model == "plumb_bob" and math.isclose(raw_info.k[4], 500.0)
    assert raw_info.header.frame_id == "camera_optical_frame"


def test_the_ros_subscription_lives_only_while_a_client_watches():
    with InProcessGraph() as g:
        bridge = _bridge(g)
        pub = g.node("foxglove_watch_publisher").create_publisher(JointState, "joint_states", 10)
        g.wait_for(lambda: "/joint_states" in bridge.view.channels.types())
        with FoxgloveClient(bridge.view.port) as client:
            channel = client.wait_for_channels({"/joint_states"})["/joint_states"]
            subs = client.subscribe({"/joint_states": channel})
            g.wait_for(lambda: pub.get_subscription_count() == 1)
            client.send_op("unsubscribe", subscriptionIds=list(subs))
            g.wait_for(lambda: pub.get_subscription_count() == 0)
            client.subscribe({"/joint_states": channel})
            g.wait_for(lambda: pub.get_subscription_count() == 1)
        # the client went away: its subscriptions with it
        g.wait_for(lambda: pub.get_subscription_count() == 0)


def test_a_port_in_use_stops_the_node_naming_the_parameters():
    context = rclpy.context.Context()
    rclpy.init(context=context)
    try:
        with socket.socket() as taken:
            taken.bind(("127.0.0.1", 0))
            taken.listen()
            port = taken.getsockname()[1]
            with pytest.raises(ParameterError, match=f"'host', 'port'.*127.0.0.1:{port}"):
                FoxgloveBridgeNode(context=context, parameter_overrides=[
                    Parameter("port", value=port)])
    finally:
        rclpy.try_shutdown(context=context)


def test_build_nodes_adds_the_bridge_with_the_options_address():
    context = rclpy.context.Context()
    rclpy.init(context=context)
    try:
        nodes = run.build_nodes("sim", {}, context, layers=(), foxglove=("127.0.0.1", 0))
        try:
            assert [n.get_name() for n in nodes] == ["foxglove_bridge"]
            assert nodes[0].params["host"] == "127.0.0.1" and nodes[0].view.port > 0
        finally:
            for n in nodes:
                n.destroy_node()
        assert run.build_nodes("sim", {}, context, layers=()) == []
    finally:
        rclpy.try_shutdown(context=context)


def test_katana_run_serves_its_graph_to_a_client():
    """katana-run --foxglove 0 (perception layer: its nodes publish without the arm) says where
    to connect; the client gets /diagnostics from perception_node, decoded with the advertised
    schema; Ctrl-C ends the run cleanly with the server."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "katana_bringup.run", "--layers", "perception", "--foxglove", "0",
         "--duration", "120"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env=private_ros_env())
    try:
        found = wait_for_output(proc.stdout, r"connect the app to ws://127\.0\.0\.1:(\d+)", 90)
        assert found, "katana-run never said where the Foxglove server listens"
        url = int(found.group(1))
        with FoxgloveClient(url) as client:
            channels = client.wait_for_channels({"/diagnostics", "/fovea/markers",
                                                 "/memory/blocks", "/perception/detections"})
            subs = client.subscribe({"/diagnostics": channels["/diagnostics"]})
            event = client.next_event()
            while not isinstance(event, MessageFrame):  # bounded by the socket's timeout
                event = client.next_event()
            assert subs[event.subscription] == "/diagnostics"
            array = _decode_without_ros(channels["/diagnostics"], event.payload)
            assert "perception_node: camera" in [status.name for status in array.status]
    finally:
        _took, out, err = stop_process(proc, signal.SIGINT)
    assert proc.returncode == 0, err
    assert "Traceback" not in out + err


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_the_console_script_serves_until_a_signal(sig):
    """foxglove_bridge alone (as sim.launch.py foxglove:=true starts it) logs its address,
    serves a client, and ends cleanly on a signal."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "katana_bringup.foxglove_bridge", "--ros-args", "-p", "port:=0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=private_ros_env())
    try:
        found = wait_for_output(proc.stderr, r"Foxglove live view on ws://127\.0\.0\.1:(\d+)", 60)
        assert found, "foxglove_bridge never logged its address"
        port = int(found.group(1))
        with FoxgloveClient(port) as client:
            assert client.next_event()["op"] == "serverInfo"
    finally:
        _took, out, err = stop_process(proc, sig)
    assert proc.returncode == 0, err
    assert "Traceback" not in out + err


def test_katana_demo_keeps_the_debug_image_for_a_watcher(tmp_path):
    """Headless katana-demo turns perception's debug image off; with --foxglove it stays on
    (drawn only while a panel shows it)."""
    plain, _ = demo.parse(["--out", str(tmp_path / "a")])
    watched, _ = demo.parse(["--out", str(tmp_path / "b"), "--foxglove", "0"])
    assert plain.param_set.values()["perception_node"]["publish_debug_image"] is False
    assert watched.param_set.values()["perception_node"]["publish_debug_image"] is True


@pytest.mark.parametrize("tool", [run, demo], ids=["katana-run", "katana-demo"])
@pytest.mark.parametrize("argv,names", [
    (["--foxglove", "65536"], "argument --foxglove: must be in [0, 65535], got 65536"),
    (["--foxglove", "port"], "argument --foxglove: expected a whole number, got 'port'"),
    (["--foxglove-host", ""], "argument --foxglove-host: expected a host name or address"),
])
def test_a_bad_foxglove_option_is_refused_with_the_usage(tool, argv, names, capsys, tmp_path,
                                                         monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as end:
        tool.main(argv)
    assert end.value.code == 2
    err = capsys.readouterr().err
    prog = "katana-run" if tool is run else "katana-demo"
    assert f"usage: {prog} " in err and f"{prog}: error: {names}" in err
    assert list(tmp_path.iterdir()) == []  # nothing made (katana-demo's run folder)
