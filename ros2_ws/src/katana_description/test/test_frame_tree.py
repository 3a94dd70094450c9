"""frame_publisher's frame tree (ROS-free): the URDF's transforms composed from the base equal
PyBullet's own forward kinematics of the same file, and the camera frames follow REP 103."""

from __future__ import annotations

import math

import numpy as np
import pybullet as p
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_description import models as m
from katana_description import urdf_path
from katana_description.core.frame_tree import (
    UrdfTree,
    camera_rotation_from_rpy,
    compose,
    load_extrinsics,
    scene_transforms,
)
from scipy.spatial.transform import Rotation

MODELS = sorted(m.MODELS)


@pytest.fixture(scope="module")
def bullet():
    """One PyBullet client with every arm model loaded (fixed base at the origin)."""
    cid = p.connect(p.DIRECT)
    bodies = {}
    for model in MODELS:
        body = p.loadURDF(str(urdf_path(f"katana_{model}.urdf")), useFixedBase=True,
                          physicsClientId=cid)
        joints = {}
        links = {}
        for i in range(p.getNumJoints(body, physicsClientId=cid)):
            info = p.getJointInfo(body, i, physicsClientId=cid)
            joints[info[1].decode()] = i
            links[info[12].decode()] = i
        bodies[model] = (body, joints, links)
    yield cid, bodies
    p.disconnect(cid)


def _positions():
    return st.tuples(*(st.floats(*m.JOINT_LIMITS[n], allow_nan=False) for n in m.ALL_JOINTS))


@settings(max_examples=40, deadline=None)
@given(model=st.sampled_from(MODELS), q=_positions())
def test_links_at_random_joint_positions_are_where_pybullet_puts_them(bullet, model, q):
    cid, bodies = bullet
    body, joints, links = bodies[model]
    positions = dict(zip(m.ALL_JOINTS, q, strict=True))
    for name, value in positions.items():
        p.resetJointState(body, joints[name], value, physicsClientId=cid)
    tree = UrdfTree(urdf_path(f"katana_{model}.urdf").read_text())
    poses = compose([*tree.fixed_transforms(), *tree.moving_transforms(positions)], tree.root)
    assert set(poses) == set(tree.links)
    for link, index in links.items():
        state = p.getLinkState(body, index, computeForwardKinematics=True, physicsClientId=cid)
        want = np.eye(4)
        want[:3, :3] = Rotation.from_quat(state[5]).as_matrix()
        want[:3, 3] = state[4]
        # PyBullet computes in single precision internally (about 5e-8 here)
        np.testing.assert_allclose(poses[link], want, atol=1e-6, err_msg=link)


def test_fixed_joints_go_static_and_moving_joints_only_when_named():
    tree = UrdfTree(urdf_path(f"katana_{m.DEFAULT_MODEL}.urdf").read_text())
    assert {t.child for t in tree.fixed_transforms()} == {
        "katana_gripper_link", "katana_gripper_tool_frame"}
    assert set(tree.moving_joints) == set(m.ALL_JOINTS)
    only_pan = tree.moving_transforms({"katana_motor1_pan_joint": 0.5, "not_a_joint": 1.0})
    assert [(t.parent, t.child) for t in only_pan] == [
        ("katana_base_link", "katana_motor1_pan_link")]
    # pan about +z by 0.5 rad, 0.2015 m above the base
    np.testing.assert_allclose(only_pan[0].rotation.as_rotvec(), (0, 0, 0.5), atol=1e-12)
    assert only_pan[0].translation == pytest.approx((0.0, 0.0, m.BASE_HEIGHT))


SMALL = """<robot name="small">
  <link name="a"/><link name="b"/><link name="c"/><link name="d"/>
  <joint name="slide" type="prismatic"><parent link="a"/><child link="b"/>
    <origin xyz="1 0 0" rpy="0 0 1.5707963267948966"/><axis xyz="1 0 0"/></joint>
  <joint name="turn" type="continuous"><parent link="b"/><child link="c"/>
    <axis xyz="0 1 0"/><mimic joint="slide" multiplier="2" offset="0.1"/></joint>
  <joint name="glue" type="fixed"><parent link="c"/><child link="d"/></joint>
</robot>"""


def test_prismatic_and_mimic_joints_as_robot_state_publisher_moves_them():
    tree = UrdfTree(SMALL)
    slide, turn = tree.moving_transforms({"slide": 0.25})
    # the prismatic axis is x of the joint frame, turned 90 degrees: world +y
    assert slide.translation == pytest.approx((1.0, 0.25, 0.0))
    np.testing.assert_allclose(turn.rotation.as_rotvec(), (0, 2 * 0.25 + 0.1, 0), atol=1e-12)
    assert [t.child for t in tree.fixed_transforms()] == ["d"]


@pytest.mark.parametrize("text", ["<robot", "<model/>", SMALL.replace(
    '<joint name="glue" type="fixed"><parent link="c"/><child link="d"/></joint>', "")])
def test_what_is_not_a_urdf_tree_is_refused(text):
    with pytest.raises(ValueError):
        UrdfTree(text)


@settings(max_examples=30, deadline=None)
@given(rpy=st.tuples(*[st.floats(-math.pi, math.pi)] * 3),
       xyz=st.tuples(*[st.floats(-2.0, 2.0)] * 3))
def test_camera_frames_follow_rep_103(rpy, xyz):
    rotation = camera_rotation_from_rpy(rpy)
    poses = compose(scene_transforms("world", "katana_base_link", "camera_link",
                                     "camera_optical_frame", xyz, rotation), "world")
    np.testing.assert_allclose(poses["katana_base_link"], np.eye(4))
    optical, link = poses["camera_optical_frame"], poses["camera_link"]
    # the optical frame is where camera_rpy puts it: R = Rz(yaw) Ry(pitch) Rx(roll)
    roll, pitch, yaw = rpy
    rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0],
                   [0, 0, 1]])
    ry = np.array([[math.cos(pitch), 0, math.sin(pitch)], [0, 1, 0],
                   [-math.sin(pitch), 0, math.cos(pitch)]])
    rx = np.array([[1, 0, 0], [0, math.cos(roll), -math.sin(roll)],
                   [0, math.sin(roll), math.cos(roll)]])
    np.testing.assert_allclose(optical[:3, :3], rz @ ry @ rx, atol=1e-12)
    np.testing.assert_allclose(optical[:3, 3], xyz, atol=1e-12)
    np.testing.assert_allclose(link[:3, 3], xyz, atol=1e-12)
    # REP 103: link x (forward) = optical z, link y (left) = -optical x, link z (up) = -optical y
    np.testing.assert_allclose(link[:3, 0], optical[:3, 2], atol=1e-12)
    np.testing.assert_allclose(link[:3, 1], -optical[:3, 0], atol=1e-12)
    np.testing.assert_allclose(link[:3, 2], -optical[:3, 1], atol=1e-12)


def test_the_default_overhead_camera_looks_down_with_image_x_along_world_minus_y():
    poses = compose(scene_transforms("world", "base", "camera_link", "camera_optical_frame",
                                     m.CAMERA_POSITION,
                                     camera_rotation_from_rpy(m.CAMERA_RPY)), "world")
    optical = poses["camera_optical_frame"]
    np.testing.assert_allclose(optical[:3, 2], (0, 0, -1), atol=1e-12)  # looks down
    np.testing.assert_allclose(optical[:3, 0], (0, -1, 0), atol=1e-12)  # image x: world -y
    np.testing.assert_allclose(poses["camera_link"][:3, 0], (0, 0, -1), atol=1e-12)


def test_extrinsics_file_gives_the_optical_frame_pose(tmp_path):
    path = tmp_path / "extrinsics.yaml"
    q = Rotation.from_euler("xyz", (3.0, 0.1, -1.4)).as_quat()
    path.write_text(yaml.safe_dump({
        "parent_frame": "world", "child_frame": "camera_optical_frame",
        "translation": {"x": 0.2, "y": -0.01, "z": 0.74},
        "rotation": dict(zip("xyzw", (float(v) for v in q), strict=True))}))
    position, rotation = load_extrinsics(str(path))
    assert position == pytest.approx((0.2, -0.01, 0.74))
    assert rotation.approx_equal(Rotation.from_quat(q), atol=1e-12)
    path.write_text("translation: {x: 1}\n")
    with pytest.raises(ValueError, match="not an extrinsics YAML"):
        load_extrinsics(str(path))
