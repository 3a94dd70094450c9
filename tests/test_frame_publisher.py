"""frame_publisher in its own rclpy Context, checked against independent computations: the
frames it publishes, composed from the world, are where the project's kinematics
(katana_manipulation KatanaKinematics) put the arm's links, and a world point projected through
the published camera frame lands on the pixel the perception's calibration
(katana_perception Calibration) gives; robot_description is the URDF, kept for late joiners."""

from __future__ import annotations

import math

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_bringup.in_process import InProcessGraph
from katana_common.params import ParameterError
from katana_common.qos import JOINT_STATE_QOS, ROBOT_DESCRIPTION_QOS, TF_QOS, TF_STATIC_QOS
from katana_description import models as m
from katana_description import urdf_path
from katana_description.frame_publisher import FramePublisher
from katana_manipulation.core.kinematics import KatanaKinematics
from katana_perception.core.calibration import Calibration, default_camera_matrix
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

#: KatanaKinematics.chain's frames, in its order, by URDF link
CHAIN_LINKS = ("katana_motor1_pan_link", "katana_motor2_lift_link", "katana_motor3_lift_link",
               "katana_motor4_lift_link", "katana_motor5_wrist_roll_link", "katana_gripper_link",
               "katana_gripper_tool_frame")
#: the URDF rounds pi/2 and pi to 1.5708 and 3.14159; the kinematics use them exactly
URDF_ROUNDING_M = 2e-5


def _matrix(msg) -> np.ndarray:
    """4x4 pose of a TransformStamped's child in its parent."""
    t, r = msg.transform.translation, msg.transform.rotation
    out = np.eye(4)
    out[:3, :3] = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
    out[:3, 3] = (t.x, t.y, t.z)
    return out


def _in_world(transforms, world: str = "world") -> dict[str, np.ndarray]:
    """The frames reachable from `world` through the messages' transforms, posed in it."""
    poses = {world: np.eye(4)}
    pending = list(transforms)
    while pending:
        ready = [t for t in pending if t.header.frame_id in poses]
        if not ready:  # the rest hang from frames not (yet) connected
            break
        for t in ready:
            poses[t.child_frame_id] = poses[t.header.frame_id] @ _matrix(t)
            pending.remove(t)
    return poses


class Listener:
    """A late subscriber of everything frame_publisher publishes, in the graph's context."""

    def __init__(self, graph: InProcessGraph, name: str) -> None:
        self.node = node = graph.node(name)
        self.static: list[TFMessage] = []
        self.tf: list[TFMessage] = []
        self.description: list[str] = []
        node.create_subscription(TFMessage, "/tf_static", self.static.append, TF_STATIC_QOS)
        node.create_subscription(TFMessage, "/tf", self.tf.append, TF_QOS)
        node.create_subscription(String, "robot_description",
                                 lambda msg: self.description.append(msg.data),
                                 ROBOT_DESCRIPTION_QOS)
        self.joints = node.create_publisher(JointState, "joint_states", JOINT_STATE_QOS)


@pytest.fixture(scope="module")
def graph():
    g = InProcessGraph(threads=2)
    try:
        g.add(FramePublisher(context=g.context))
        yield g
    finally:
        g.close()


@pytest.fixture(scope="module")
def listener(graph):
    # built after the node has published robot_description and /tf_static: a late joiner
    return Listener(graph, "frame_test_listener")


def test_a_late_subscriber_gets_the_urdf_and_every_static_frame(graph, listener):
    urdf = graph.wait_for(lambda: listener.description and listener.description[-1])
    assert urdf == urdf_path(f"katana_{m.DEFAULT_MODEL}.urdf").read_text(encoding="utf-8")
    static = graph.wait_for(lambda: listener.static and listener.static[-1]).transforms
    assert {(t.header.frame_id, t.child_frame_id) for t in static} == {
        ("world", "katana_base_link"), ("world", "camera_link"),
        ("camera_link", "camera_optical_frame"),
        ("katana_motor5_wrist_roll_link", "katana_gripper_link"),
        ("katana_gripper_link", "katana_gripper_tool_frame")}
    assert len(listener.static) == 1  # one message: the topic keeps only the last


_stamp = iter(range(1, 10**6))


@settings(max_examples=25, deadline=None)
@given(q=st.tuples(*(st.floats(*m.JOINT_LIMITS[n], allow_nan=False) for n in m.ALL_JOINTS)))
def test_links_at_random_joint_positions_are_where_the_kinematics_put_them(graph, listener, q):
    stamp = Time(sec=next(_stamp), nanosec=250)
    msg = JointState(name=list(m.ALL_JOINTS), position=list(q))
    msg.header.stamp = stamp
    listener.joints.publish(msg)
    moving = graph.wait_for(lambda: next(
        (t for t in reversed(listener.tf) if t.transforms[0].header.stamp == stamp), None))
    assert all(t.header.stamp == stamp for t in moving.transforms)
    assert {t.child_frame_id for t in moving.transforms} == {
        "katana_motor1_pan_link", "katana_motor2_lift_link", "katana_motor3_lift_link",
        "katana_motor4_lift_link", "katana_motor5_wrist_roll_link", "katana_r_finger_link",
        "katana_l_finger_link"}
    poses = _in_world([*listener.static[-1].transforms, *moving.transforms])
    for link, want in zip(CHAIN_LINKS, KatanaKinematics(m.DEFAULT_MODEL).chain(q[:5]),
                          strict=True):
        np.testing.assert_allclose(poses[link][:3, 3], want[:3, 3], atol=URDF_ROUNDING_M,
                                   err_msg=link)
        np.testing.assert_allclose(poses[link][:3, :3], want[:3, :3], atol=1e-4, err_msg=link)
    # each finger turns about the gripper's z by its own angle (r) or the mirrored one (l)
    grip = poses["katana_gripper_link"]
    for name, sign, angle in (("katana_r_finger_link", 1, q[5]), ("katana_l_finger_link", -1,
                                                                   q[6])):
        relative = np.linalg.inv(grip) @ poses[name]
        assert math.atan2(relative[1, 0], relative[0, 0]) * sign == pytest.approx(
            math.remainder(angle, 2 * math.pi), abs=1e-4)


def test_a_joint_states_message_without_positions_is_ignored(graph, listener):
    before = len(listener.tf)
    listener.joints.publish(JointState(name=["katana_motor1_pan_joint"], position=[]))
    stamp = Time(sec=2 * 10**6)
    msg = JointState(name=["katana_motor1_pan_joint"], position=[0.1])
    msg.header.stamp = stamp
    listener.joints.publish(msg)  # delivered in order after the bad one
    graph.wait_for(lambda: any(t.transforms[0].header.stamp == stamp for t in listener.tf))
    assert len(listener.tf) == before + 1


def _world_points(n: int = 50) -> np.ndarray:
    rng = np.random.default_rng(7)
    return np.column_stack([rng.uniform(0.0, 0.45, n), rng.uniform(-0.3, 0.3, n),
                            rng.uniform(0.0, 0.2, n)])


def _pixels_through(optical_in_world: np.ndarray, K: np.ndarray, points: np.ndarray):
    """Pinhole projection of world points through a camera posed at `optical_in_world`."""
    world_to_camera = np.linalg.inv(optical_in_world)
    cam = (world_to_camera[:3, :3] @ points.T).T + world_to_camera[:3, 3]
    uvw = (K @ cam.T).T
    return uvw[:, :2] / uvw[:, 2:]


def test_the_camera_frame_projects_as_the_perceptions_calibration(graph, listener):
    poses = _in_world(graph.wait_for(lambda: listener.static and listener.static[-1]).transforms)
    K = default_camera_matrix()
    calibration = Calibration.from_camera_rpy(K, m.CAMERA_POSITION, m.CAMERA_RPY)
    points = _world_points()
    np.testing.assert_allclose(_pixels_through(poses["camera_optical_frame"], K, points),
                               calibration.project(points), atol=1e-6)


def test_a_calibrated_camera_from_the_extrinsics_file_too(tmp_path):
    """katana-calibrate's files (written by the perception's own Calibration.save) replace
    camera_position and camera_rpy for frame_publisher as for the perception."""
    K = np.array([[812.0, 0.0, 331.0], [0.0, 809.0, 242.5], [0.0, 0.0, 1.0]])
    solved = Calibration.from_camera_rpy(K, (0.21, 0.015, 0.74), (3.1, 0.04, -1.52))
    solved.save(tmp_path / "camera_info.yaml", tmp_path / "extrinsics.yaml")
    perception = Calibration.load(tmp_path / "camera_info.yaml", tmp_path / "extrinsics.yaml")
    with InProcessGraph(threads=2) as g:
        g.add(FramePublisher(context=g.context, parameter_overrides=[
            Parameter("extrinsics_file", value=str(tmp_path / "extrinsics.yaml")),
            Parameter("robot_frames", value=False)]))
        listener = Listener(g, "frame_test_calibrated")
        static = g.wait_for(lambda: listener.static and listener.static[-1]).transforms
        assert {t.child_frame_id for t in static} == {
            "katana_base_link", "camera_link", "camera_optical_frame"}
        assert listener.node.count_publishers("/robot_description") == 0
        assert listener.node.count_subscribers("/joint_states") == 0
    points = _world_points()
    np.testing.assert_allclose(_pixels_through(_in_world(static)["camera_optical_frame"], K,
                                               points), perception.project(points), atol=1e-6)


def test_topics_have_robot_state_publishers_qos(graph, listener):
    """As tf2_ros's broadcasters and robot_state_publisher offer them (reliable everywhere;
    /tf volatile, /tf_static and robot_description transient local), so that either publisher
    serves the same subscribers."""
    want = {"/tf": DurabilityPolicy.VOLATILE, "/tf_static": DurabilityPolicy.TRANSIENT_LOCAL,
            "/robot_description": DurabilityPolicy.TRANSIENT_LOCAL}
    for topic, durability in want.items():
        (info,) = [i for i in listener.node.get_publishers_info_by_topic(topic)
                   if i.node_name == "frame_publisher"]
        assert info.qos_profile.durability == durability, topic
        assert info.qos_profile.reliability == ReliabilityPolicy.RELIABLE, topic
    (sub,) = [i for i in listener.node.get_subscriptions_info_by_topic("/joint_states")
              if i.node_name == "frame_publisher"]
    assert sub.qos_profile.reliability == ReliabilityPolicy.RELIABLE


def test_a_missing_extrinsics_file_stops_the_node_at_start_up(tmp_path):
    with InProcessGraph(threads=2) as g, pytest.raises(ParameterError, match="extrinsics_file"):
        FramePublisher(context=g.context, parameter_overrides=[
            Parameter("extrinsics_file", value=str(tmp_path / "missing.yaml"))])
