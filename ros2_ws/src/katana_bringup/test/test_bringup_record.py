"""katana-run --record: the recorder writes a rosbag2 MCAP file that the mcap library reads back
(topics, types, counts, and every message decoded with the file's own schemas by
mcap-ros2-support, as Foxglove and rosbag2 decode it); a SIGKILL leaves what was written
readable."""

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
from katana_bringup.recording import message_definition, read_recording
from katana_common.qos import EVENT_QOS, SENSOR_QOS, STATE_QOS, TF_STATIC_QOS
from katana_common.testing import private_ros_env
from katana_interfaces.msg import Block, BlockArray, Experience, LearnerState
from mcap.exceptions import McapError
from mcap.reader import make_reader
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import Image, JointState
from tf2_msgs.msg import TFMessage


def _read(path: Path) -> dict[str, list]:
    """topic -> [(type name, decoded message)], decoded with the file's own schemas."""
    out: dict[str, list] = {}
    for topic, type_name, _log_ns, decoded in read_recording(path):
        out.setdefault(topic, []).append((type_name, decoded))
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
        g.wait_for(lambda: rec.recording.counts["/curiosity/experience"] == 5
                   and rec.recording.counts["/memory/blocks"] == 5
                   and rec.recording.counts["/joint_states"] == 5
                   and rec.recording.counts["/curiosity/learner_state"] == 1)
        assert rec.recording.counts["/camera/image_raw"] == 0  # image_rate_hz 0: none
        rec.set_parameters([Parameter("image_rate_hz", value=100.0)])  # live
        images.publish(Image(width=1, height=1, encoding="rgb8", step=3, data=b"xyz"))
        g.wait_for(lambda: rec.recording.counts["/camera/image_raw"] == 1)
        rec.stop()
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
    with open(path, "rb") as fh:  # a summary was written: the file is indexed
        summary = make_reader(fh).get_summary()
    assert summary is not None and summary.statistics.message_count == 17


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
        g.wait_for(lambda: rec.recording.counts["/tf_static"] == 1)
        rec.stop()
    (got,) = _read(path)["/tf_static"]
    assert got[0] == "tf2_msgs/msg/TFMessage"
    (t,) = got[1].transforms
    assert (t.header.frame_id, t.child_frame_id, t.transform.translation.z) == (
        "world", "camera_link", 0.75)


def _env() -> dict:
    return private_ros_env()


@pytest.mark.timeout(120)
def test_sigkill_leaves_a_readable_file(tmp_path, monkeypatch):
    path = tmp_path / "killed.mcap"
    env = _env()
    proc = subprocess.Popen(
        [sys.executable, "-m", "katana_bringup.recorder_node", "--ros-args",
         "-p", f"path:={path}"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
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
        while True:  # bounded: until the 20 are on disk, read as a crash would leave them
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
    with open(path, "rb") as fh:  # no footer: the writer never finished, seeking fails
        with pytest.raises(McapError):
            make_reader(fh).get_summary()
    got = _read(path)
    assert [m.index for _, m in got["/curiosity/experience"]] == list(range(20))
    assert {t for t, _ in got["/curiosity/experience"]} == {"katana_interfaces/msg/Experience"}
