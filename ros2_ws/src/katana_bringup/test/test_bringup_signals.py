"""SIGINT and SIGTERM end each perception node, the recorder (within 2 s) and katana-run
(within 3 s) with exit code 0 and no traceback, started as separate processes as `ros2 launch`
starts them; the perception node while it is segmenting a stream of camera frames."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from katana_bringup.recording import read_recording
from katana_common.qos import SENSOR_QOS
from katana_common.testing import probe_node, stop_process, use_private_domain
from katana_perception.core.calibration import Calibration
from katana_perception.core.synthetic import Renderer, stack_block
from katana_perception.messages import rgb_to_image
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header

pytestmark = pytest.mark.timeout(300)
NODE_LIMIT_S = 2.0  # every node ends within 2 s of the signal
RUN_LIMIT_S = 3.0  # and katana-run within 3 s


@pytest.fixture
def probe(monkeypatch):
    """A node in the test process, on a domain of this test process only."""
    use_private_domain(monkeypatch)
    with probe_node("signal_test_probe") as (node, ex):
        yield node, ex


def _camera_msgs():
    calib = Calibration.overhead_default()
    info = CameraInfo(width=calib.width, height=calib.height, distortion_model="plumb_bob")
    info.k = calib.K.ravel().tolist()
    info.d = [0.0] * 5
    info.r = np.eye(3).ravel().tolist()
    info.p = np.hstack([calib.K, np.zeros((3, 1))]).ravel().tolist()
    rgb = Renderer(calib).render([stack_block("red", 0.2, 0.05, 1, 0.1)])[0]
    return info, rgb_to_image(rgb, Header(frame_id="camera_optical_frame"))


#: what each node creates last in its constructor
READY = {"perception_node": "/perception/judge_placement", "fovea_node": "/fovea/find_placement",
         "block_memory_node": "/camera/camera_info", "run_recorder": "/curiosity/markers"}


def _ready(node: Node, name: str) -> bool:
    if name not in node.get_node_names():
        return False
    what = READY[name]
    if what.startswith(("/perception/", "/fovea/")):
        return what in dict(node.get_service_names_and_types())
    return name in {i.node_name for i in node.get_subscriptions_info_by_topic(what)}


def _wait_and_signal(proc, probe, name: str, sig: int, feed: bool,
                     until=None) -> tuple[float, str, str]:
    """Wait until `name` is up (and, with `feed`, busy with camera frames), then stop `proc`
    with `sig`: katana_common.testing.stop_process's (seconds, stdout, stderr)."""
    node, ex = probe
    info_pub = node.create_publisher(CameraInfo, "camera/camera_info", SENSOR_QOS)
    image_pub = node.create_publisher(Image, "camera/image_raw", SENSOR_QOS)
    info, image = _camera_msgs()
    deadline = time.monotonic() + 90
    while not _ready(node, name):  # fully built: its last service or subscription is there
        assert proc.poll() is None, proc.communicate()[1]
        assert time.monotonic() < deadline, f"{name} never joined the graph"
        ex.spin_once(timeout_sec=0.1)
    if feed:  # mid-work: frames keep arriving while the signal comes
        # block memory takes camera_info only, the others images too: wait for either
        while (image_pub.get_subscription_count() == 0 and info_pub.get_subscription_count() == 0
               and time.monotonic() < deadline):
            ex.spin_once(timeout_sec=0.05)
        for _ in range(10):
            info_pub.publish(info)
            image_pub.publish(image)
            ex.spin_once(timeout_sec=0.05)
        while until is not None and not until():  # bounded: frames until the work shows
            assert time.monotonic() < deadline, "the frames were never processed"
            info_pub.publish(info)
            image_pub.publish(image)
            ex.spin_once(timeout_sec=0.1)
    return stop_process(proc, sig)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("module,name,feed", [
    ("katana_perception.perception_node", "perception_node", True),
    ("katana_perception.block_memory_node", "block_memory_node", True),
    ("katana_perception.fovea_node", "fovea_node", False),
    ("katana_bringup.recorder_node", "run_recorder", True),

])
def test_a_signal_ends_the_node_cleanly(probe, tmp_path, module, name, feed, sig):
    extra = ["-p", f"path:={tmp_path / 'r.mcap'}"] if name == "run_recorder" else []
    proc = subprocess.Popen([sys.executable, "-m", module, "--ros-args", *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    took, out, err = _wait_and_signal(proc, probe, name, sig, feed)
    assert proc.returncode == 0, err
    assert "Traceback" not in out + err, err
    assert took <= NODE_LIMIT_S, f"{name} took {took:.2f} s to stop"


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_ends_katana_run_cleanly(probe, tmp_path, sig):
    mcap = tmp_path / "run.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-m", "katana_bringup.run", "--layers", "perception",
         "--record", str(mcap)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def detections_recorded() -> bool:
        return mcap.exists() and any(
            t == "/perception/detections" for t, *_ in read_recording(mcap))

    took, out, err = _wait_and_signal(proc, probe, "fovea_node", sig, feed=True,
                                      until=detections_recorded)
    assert proc.returncode == 0, err
    assert "Traceback" not in out + err, err
    assert took <= RUN_LIMIT_S, f"katana-run took {took:.2f} s to stop"
    topics = {topic for topic, *_ in read_recording(mcap)}
    assert "/perception/detections" in topics  # the recording was closed properly
