"""katana-run --record: the recorder writes a rosbag2 MCAP file that the independent rosbags
reader opens (topics, types, counts, each channel's offered QoS, and every message decoded with
the file's own schemas), as does mcap-ros2-support; a SIGKILL leaves every message up to the
last flush, which `repair` (katana-play --repair) makes an indexed file rosbags reads."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rclpy
from geometry_msgs.msg import TransformStamped
from katana_bringup.in_process import InProcessGraph
from katana_bringup.recorder_node import TOPICS, RecorderNode
from katana_bringup.recording import is_indexed, message_definition, read_recording, repair
from katana_common.qos import EVENT_QOS, SENSOR_QOS, STATE_QOS, TF_STATIC_QOS
from katana_common.testing import private_ros_env
from katana_interfaces.msg import Block, BlockArray, Experience, LearnerState
from mcap.reader import make_reader
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader
from sensor_msgs.msg import Image, JointState
from tf2_msgs.msg import TFMessage


def _read(path: Path) -> dict[str, list]:
    """topic -> [(type name, decoded message)], decoded with the file's own schemas."""
    out: dict[str, list] = {}
    for topic, type_name, _log_ns, decoded in read_recording(path):
        out.setdefault(topic, []).append((type_name, decoded))
    return out


def _read_with_rosbags(path: Path) -> dict[str, list]:
    """topic -> [(type name, message)], read and decoded by rosbags from the file alone."""
    out: dict[str, list] = {}
    with AnyReader([path]) as reader:
        for conn, _t, raw in reader.messages():
            out.setdefault(conn.topic, []).append(
                (conn.msgtype, reader.deserialize(raw, conn.msgtype)))
    return out


def test_every_recorded_type_has_a_complete_schema():
    for _topic, _cls, type_name, _qos, _throttled in TOPICS:
        text = message_definition(type_name)
        assert "MSG: std_msgs/Header" in text or type_name.endswith("LearnerState")


def test_a_short_recording_reads_back_with_topics_types_and_counts(tmp_path):
    path = tmp_path / "run.mcap"
    with InProcessGraph() as g:
        rec = RecorderNode(context=g.context, parameter_overrides=[
            Parameter("path", value=str(path)), Parameter("image_rate_hz", value=0.0)])
        g.add(rec)
        pub = Node("record_test_publisher", context=g.context)
        g.add(pub)
        blocks = pub.create_publisher(BlockArray, "memory/blocks", STATE_QOS)
        exp = pub.create_publisher(Experience, "curiosity/experience", EVENT_QOS)
        joints = pub.create_publisher(JointState, "joint_states", 10)
        images = pub.create_publisher(Image, "camera/image_raw", SENSOR_QOS)
        state = pub.create_publisher(LearnerState, "curiosity/learner_state", STATE_QOS)
        g.wait_for(lambda: all(p.get_subscription_count() > 0
                               for p in (blocks, exp, joints, images, state)))
        for i in range(5):
            b = Block(id="red", level=1 + i)
            b.pose.position.x = 0.2 + i / 100
            blocks.publish(BlockArray(blocks=[b]))
            exp.publish(Experience(index=i, label=1 if i % 2 else -1, moved_block="red"))
            joints.publish(JointState(name=["a"], position=[float(i)]))
            images.publish(Image(width=1, height=1, encoding="rgb8", step=3, data=b"abc"))
        state.publish(LearnerState())
        counts = rec.recording.counts
        g.wait_for(lambda: counts.get("/curiosity/experience") == 5
                   and counts.get("/memory/blocks") == 5 and counts.get("/joint_states") == 5
                   and counts.get("/curiosity/learner_state") == 1)
        assert "/camera/image_raw" not in counts  # image_rate_hz 0: none, not even a channel
        rec.set_parameters([Parameter("image_rate_hz", value=100.0)])  # live
        images.publish(Image(width=1, height=1, encoding="rgb8", step=3, data=b"xyz"))
        g.wait_for(lambda: counts.get("/camera/image_raw") == 1)
        rec.stop()
    with Reader(path) as bag:  # rosbags' rosbag2 reader: the file alone, through its index
        conns = {c.topic: c for c in bag.connections}
    assert {t: c.msgcount for t, c in conns.items()} == {
        "/memory/blocks": 5, "/curiosity/experience": 5, "/joint_states": 5,
        "/curiosity/learner_state": 1, "/camera/image_raw": 1}
    durability = {t: [q.durability.name for q in c.ext.offered_qos_profiles]
                  for t, c in conns.items()}
    assert durability["/memory/blocks"] == ["TRANSIENT_LOCAL"]  # as its publisher offered
    assert durability["/curiosity/learner_state"] == ["TRANSIENT_LOCAL"]
    assert durability["/curiosity/experience"] == ["VOLATILE"]
    assert [q.reliability.name for q in conns["/camera/image_raw"].ext.offered_qos_profiles
            ] == ["BEST_EFFORT"]
    by_rosbags = _read_with_rosbags(path)
    assert [m.blocks[0].level for _, m in by_rosbags["/memory/blocks"]] == [1, 2, 3, 4, 5]
    assert [m.label for _, m in by_rosbags["/curiosity/experience"]] == [-1, 1, -1, 1, -1]
    assert [list(m.position) for _, m in by_rosbags["/joint_states"]] == [
        [float(i)] for i in range(5)]
    assert bytes(by_rosbags["/camera/image_raw"][0][1].data) == b"xyz"
    got = _read(path)
    assert {t: len(v) for t, v in got.items()} == {
        "/memory/blocks": 5, "/curiosity/experience": 5, "/joint_states": 5,
        "/curiosity/learner_state": 1, "/camera/image_raw": 1}
    assert {v[0][0] for v in got.values()} == {
        "katana_interfaces/msg/BlockArray", "katana_interfaces/msg/Experience",
        "sensor_msgs/msg/JointState", "katana_interfaces/msg/LearnerState",
        "sensor_msgs/msg/Image"}
    assert [m.blocks[0].level for _, m in got["/memory/blocks"]] == [1, 2, 3, 4, 5]
    assert [m.label for _, m in got["/curiosity/experience"]] == [-1, 1, -1, 1, -1]
    assert bytes(got["/camera/image_raw"][0][1].data) == b"xyz"
    with open(path, "rb") as fh:  # chunked, compressed, indexed
        summary = make_reader(fh).get_summary()
    assert summary is not None and summary.statistics.message_count == 17
    assert summary.chunk_indexes and {c.compression for c in summary.chunk_indexes} == {"zstd"}


def test_the_static_frames_published_before_the_recorder_are_recorded(tmp_path):
    """/tf_static is published once, at the start of the graph (frame_publisher, before the
    recorder in katana-run): the recorder still gets it, as a late joiner."""
    path = tmp_path / "run.mcap"
    static = TransformStamped(child_frame_id="camera_link")
    static.header.frame_id = "world"
    static.transform.translation.z = 0.75
    with InProcessGraph() as g:
        pub = Node("record_test_static", context=g.context)
        g.add(pub)
        pub.create_publisher(TFMessage, "/tf_static", TF_STATIC_QOS).publish(
            TFMessage(transforms=[static]))
        rec = RecorderNode(context=g.context, parameter_overrides=[
            Parameter("path", value=str(path))])
        g.add(rec)
        g.wait_for(lambda: rec.recording.counts.get("/tf_static") == 1)
        rec.stop()
    (got,) = _read(path)["/tf_static"]
    assert got[0] == "tf2_msgs/msg/TFMessage"
    (t,) = got[1].transforms
    assert (t.header.frame_id, t.child_frame_id, t.transform.translation.z) == (
        "world", "camera_link", 0.75)


def _env() -> dict:
    return private_ros_env()


@pytest.mark.timeout(120)
def test_sigkill_then_repair_keeps_every_flushed_message_for_rosbags(tmp_path, monkeypatch):
    path = tmp_path / "killed.mcap"
    env = _env()
    proc = subprocess.Popen(
        [sys.executable, "-m", "katana_bringup.recorder_node", "--ros-args",
         "-p", f"path:={path}", "-p", "flush_period_s:=0.1"], env=env,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    for key in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE"):
        monkeypatch.setenv(key, env[key])
    ctx = Context()
    rclpy.init(context=ctx)
    node = Node("kill_test_publisher", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    try:
        exp = node.create_publisher(Experience, "curiosity/experience", EVENT_QOS)
        deadline = time.monotonic() + 60
        while exp.get_subscription_count() == 0:
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.monotonic() < deadline, "the recorder never subscribed"
            ex.spin_once(timeout_sec=0.05)
        for i in range(20):
            exp.publish(Experience(index=i, label=1))
        while True:  # bounded: until a flush put the 20 on disk, read as a kill leaves them
            ex.spin_once(timeout_sec=0.05)
            try:
                n = len(_read(path).get("/curiosity/experience", []))
            except FileNotFoundError:
                n = 0
            if n == 20:
                break
            assert time.monotonic() < deadline, f"only {n} of 20 messages reached the file"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
        ex.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    assert not is_indexed(path)  # no footer: the writer never finished
    with pytest.raises(Exception, match="magic"):
        Reader(path).open()  # what rosbags says of a killed writer's file
    report = repair(path)
    assert report.repaired and report.topics == {"/curiosity/experience": 20}
    got = _read_with_rosbags(path)
    assert [m.index for _, m in got["/curiosity/experience"]] == list(range(20))
    assert {t for t, _ in got["/curiosity/experience"]} == {"katana_interfaces/msg/Experience"}
