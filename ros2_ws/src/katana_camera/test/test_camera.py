"""camera_node and its core: camera_info YAML, a SUBSTITUTE frame source, video, no camera."""

import functools
import itertools

import cv2
import numpy as np
import pytest
import rclpy
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_camera.camera_node import CameraNode, nominal_camera_info_path
from katana_camera.core.camera import (
    CameraInfoError,
    OpenCvFrameSource,
    SubstituteFrameSource,
    load_calibration,
)
from katana_common.params import ParameterError
from katana_common.qos import SENSOR_QOS
from katana_common.testing import spin_until
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, Image

pytestmark = pytest.mark.timeout(60)
_ids = itertools.count()


def write_info(path, **changes):
    doc = yaml.safe_load(open(nominal_camera_info_path(), encoding="utf-8"))
    doc.update(changes)
    path.write_text(yaml.safe_dump(doc))
    return str(path)


def test_nominal_calibration_is_the_shared_scene_camera():
    cal = load_calibration(nominal_camera_info_path())
    assert (cal.width, cal.height) == (640, 480)
    assert cal.k == (750.0, 0.0, 319.5, 0.0, 750.0, 239.5, 0.0, 0.0, 1.0)
    assert cal.p[:3] == (750.0, 0.0, 319.5) and len(cal.d) == 5


@settings(max_examples=25, deadline=None)
@given(
    st.floats(100, 3000),
    st.floats(100, 3000),
    st.floats(0, 1000),
    st.floats(0, 1000),
    st.lists(st.floats(-1, 1), min_size=5, max_size=5),
)
def test_calibration_round_trips_through_yaml(tmp_path_factory, fx, fy, cx, cy, d):
    path = tmp_path_factory.mktemp("info") / "cam.yaml"
    k = [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]
    write_info(
        path,
        camera_matrix={"rows": 3, "cols": 3, "data": k},
        distortion_coefficients={"rows": 1, "cols": 5, "data": d},
    )
    cal = load_calibration(path)
    assert cal.k == pytest.approx(tuple(k)) and cal.d == pytest.approx(tuple(d))


@pytest.mark.parametrize(
    ("changes", "text"),
    [
        ({"camera_matrix": {"rows": 3, "cols": 3, "data": [1.0, 2.0]}}, "camera_matrix"),
        ({"image_width": "wide"}, "image_width"),
        ({"distortion_coefficients": None}, "distortion_coefficients"),
        ({"camera_matrix": {"rows": 3, "cols": 3, "data": [0.0] * 9}}, "focal"),
    ],
)
def test_bad_calibration_files_say_what_is_wrong(tmp_path, changes, text):
    with pytest.raises(CameraInfoError, match=text):
        load_calibration(write_info(tmp_path / "bad.yaml", **changes))


def test_unreadable_calibration_files(tmp_path):
    with pytest.raises(CameraInfoError, match="cannot read"):
        load_calibration(tmp_path / "missing.yaml")
    (tmp_path / "junk.yaml").write_text("{unclosed: [")
    with pytest.raises(CameraInfoError, match="YAML"):
        load_calibration(tmp_path / "junk.yaml")


class CameraGraph:
    def __init__(self, frame_source=None, **params):
        self.ctx = Context()
        rclpy.init(context=self.ctx)
        n = next(_ids)
        self.node = CameraNode(
            frame_source=frame_source,
            node_name=f"camera_test_{n}",
            context=self.ctx,
            parameter_overrides=[Parameter(k, value=v) for k, v in params.items()],
        )
        self.client = Node(f"camera_test_client_{n}", context=self.ctx)
        self.images: list[Image] = []
        self.infos: list[CameraInfo] = []
        qos = SENSOR_QOS
        self.client.create_subscription(Image, "camera/image_raw", self.images.append, qos)
        self.client.create_subscription(CameraInfo, "camera/camera_info", self.infos.append, qos)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self.executor.add_node(self.client)
        self.spin_until = functools.partial(spin_until, self.executor)

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self.client.destroy_node()
        rclpy.shutdown(context=self.ctx)


@pytest.fixture
def camera_graph():
    made = []

    def make(frame_source=None, **params):
        g = CameraGraph(frame_source, **params)
        made.append(g)
        return g

    yield make
    for g in made:
        g.close()


def as_array(msg: Image) -> np.ndarray:
    return np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(msg.height, msg.width, 3)


def test_publishes_substitute_frames_with_calibration(camera_graph, tmp_path):
    info = write_info(
        tmp_path / "cam.yaml",
        camera_matrix={"rows": 3, "cols": 3, "data": [800.0, 0, 320, 0, 810.0, 240, 0, 0, 1]},
    )
    g = camera_graph(SubstituteFrameSource(), rate=30.0, camera_info_file=info)
    assert g.spin_until(lambda: len(g.images) >= 3 and len(g.infos) >= 3)
    image, cam = g.images[-1], g.infos[-1]
    assert (image.width, image.height, image.encoding) == (640, 480, "rgb8")
    assert image.header.frame_id == "camera_optical_frame"
    assert list(cam.k) == [800.0, 0, 320, 0, 810.0, 240, 0, 0, 1]
    stamps = {(i.header.stamp.sec, i.header.stamp.nanosec) for i in g.images}
    assert (cam.header.stamp.sec, cam.header.stamp.nanosec) in stamps
    pixels = as_array(image)
    assert tuple(pixels[5, 5]) == (200, 200, 200)  # the substitute's grey table
    assert not np.array_equal(as_array(g.images[0]), pixels)  # frames differ


def test_reads_a_video_file_through_opencv(camera_graph, tmp_path):
    path = str(tmp_path / "overhead.avi")
    writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (320, 240))
    assert writer.isOpened()
    for _ in range(5):
        frame = np.zeros((240, 320, 3), dtype=np.uint8)
        frame[:, :] = (255, 0, 0)  # BGR: blue
        writer.write(frame)
    writer.release()
    g = camera_graph(device=path, rate=20.0)
    assert g.spin_until(lambda: len(g.images) >= 2)
    pixel = as_array(g.images[0])[120, 160].astype(int)
    assert pixel[2] > 200 and pixel[0] < 50  # arrives as RGB: blue in the last channel
    assert g.images[0].width == 320


def test_missing_camera_is_a_clear_error_and_the_node_stays_up(camera_graph):
    g = camera_graph(device="/dev/katana_no_such_camera", reconnect_period=0.1)
    assert g.spin_until(lambda: "cannot open" in g.node.error)
    assert "device" in g.node.error
    g.spin_until(lambda: False, timeout_s=0.5)  # keeps spinning, retrying, not crashing
    assert g.node.frames_published == 0 and not g.images


def test_unplugged_camera_is_reported_and_retried(camera_graph):
    source = SubstituteFrameSource(fail_after=3)
    g = camera_graph(source, rate=30.0, reconnect_period=0.1)
    assert g.spin_until(lambda: "cannot open" in g.node.error)
    assert g.node.frames_published == 3
    source.fail_after = None  # plugged back in
    assert g.spin_until(lambda: g.node.frames_published > 5 and not g.node.error)


def test_substitute_device_parameter(camera_graph):
    g = camera_graph(device="substitute", rate=30.0)
    assert "SUBSTITUTE" in g.node.source.description
    assert g.spin_until(lambda: len(g.images) >= 1)


def test_bad_calibration_file_stops_the_node(tmp_path):
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        with pytest.raises(ParameterError, match="camera_info_file.*cannot read"):
            CameraNode(
                frame_source=SubstituteFrameSource(),
                node_name=f"camera_bad_{next(_ids)}",
                context=ctx,
                parameter_overrides=[Parameter("camera_info_file", value=str(tmp_path / "x"))],
            )
    finally:
        rclpy.shutdown(context=ctx)


def test_opencv_source_on_a_missing_device_does_not_open():
    source = OpenCvFrameSource("/dev/katana_no_such_camera")
    assert not source.open()
    assert source.read() is None


_number = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-5, 5),
                    st.booleans(), st.text(max_size=3), st.none())


@settings(max_examples=150, deadline=None)
@given(
    field=st.sampled_from(["camera_matrix", "distortion_coefficients", "projection_matrix",
                           "rectification_matrix"]),
    data=st.one_of(st.lists(_number, max_size=13), _number),
)
def test_any_camera_info_yaml_gives_finite_numbers_or_a_clear_error(tmp_path_factory, field,
                                                                    data):
    """CameraInfo K, D, R and P are finite numbers, or the file is refused naming the field."""
    path = tmp_path_factory.mktemp("info") / "cam.yaml"
    write_info(path, **{field: {"rows": 3, "cols": 3, "data": data}})
    try:
        cal = load_calibration(str(path))
    except CameraInfoError as exc:
        assert field in str(exc) or "YAML" in str(exc)
        return
    for values in (cal.k, cal.d, cal.r, cal.p):
        assert all(isinstance(v, float) and np.isfinite(v) for v in values)
    assert len(cal.k) == 9 and len(cal.r) == 9 and len(cal.p) == 12
