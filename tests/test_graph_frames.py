"""The simulated arm layer built by katana-run's build_nodes has one frame tree: /tf_static and
/tf connect the world to every link of the arm and to the frame the camera images are stamped
in, and the arm's /tf follows the simulation's joint_states (same stamp, the kinematics' pose)."""

from __future__ import annotations

import numpy as np
from katana_bringup.run import build_nodes, default_params_files, load_params
from katana_common.qos import JOINT_STATE_QOS, SENSOR_QOS, TF_QOS, TF_STATIC_QOS
from katana_description import models as m
from katana_manipulation.core.kinematics import KatanaKinematics
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import Image, JointState
from tf2_msgs.msg import TFMessage

LINKS = {"katana_base_link", "katana_motor1_pan_link", "katana_motor2_lift_link",
         "katana_motor3_lift_link", "katana_motor4_lift_link", "katana_motor5_wrist_roll_link",
         "katana_gripper_link", "katana_r_finger_link", "katana_l_finger_link",
         "katana_gripper_tool_frame"}


def _in_world(transforms) -> dict[str, np.ndarray]:
    poses = {"world": np.eye(4)}
    pending = list(transforms)
    while pending:
        ready = [t for t in pending if t.header.frame_id in poses]
        assert ready, f"not connected to the world: {[t.child_frame_id for t in pending]}"
        for t in ready:
            pose = np.eye(4)
            r, v = t.transform.rotation, t.transform.translation
            pose[:3, :3] = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
            pose[:3, 3] = (v.x, v.y, v.z)
            poses[t.child_frame_id] = poses[t.header.frame_id] @ pose
            pending.remove(t)
    return poses


def test_the_sim_graph_has_one_frame_tree(ros_graph, graph_offers):
    g = ros_graph
    g.add(*build_nodes("sim", load_params(default_params_files("sim")), g.context,
                       layers=["arm"]))
    probe = g.node("frames_graph_probe")
    graph_offers(g, probe, "topics", {"/tf": "tf2_msgs/msg/TFMessage",
                                      "/tf_static": "tf2_msgs/msg/TFMessage",
                                      "/robot_description": "std_msgs/msg/String"})
    static: list[TFMessage] = []
    tf: list[TFMessage] = []
    joints: list[JointState] = []
    images: list[Image] = []
    probe.create_subscription(TFMessage, "/tf_static", static.append, TF_STATIC_QOS)
    probe.create_subscription(TFMessage, "/tf", tf.append, TF_QOS)
    probe.create_subscription(JointState, "joint_states", joints.append, JOINT_STATE_QOS)
    probe.create_subscription(Image, "camera/image_raw", images.append, SENSOR_QOS)

    def matched():  # a joint_states message and the /tf made of it
        stamps = {(t.transforms[0].header.stamp.sec, t.transforms[0].header.stamp.nanosec): t
                  for t in list(tf)}
        for msg in reversed(list(joints)):
            key = (msg.header.stamp.sec, msg.header.stamp.nanosec)
            if key in stamps:
                return msg, stamps[key]
        return None

    state, moving = g.wait_for(matched)
    frame = g.wait_for(lambda: images and images[-1].header.frame_id)
    poses = _in_world([*g.wait_for(lambda: static and static[-1]).transforms,
                       *moving.transforms])
    assert LINKS | {"world", "camera_link", frame} <= set(poses)
    positions = dict(zip(state.name, state.position, strict=True))
    want = KatanaKinematics(m.DEFAULT_MODEL).fk([positions[n] for n in m.ARM_JOINTS])
    np.testing.assert_allclose(poses["katana_gripper_tool_frame"][:3, 3], want[:3, 3],
                               atol=2e-5)
    # the camera looks down from where the scene puts it
    np.testing.assert_allclose(poses[frame][:3, 3], m.CAMERA_POSITION, atol=1e-9)
    np.testing.assert_allclose(poses[frame][:3, 2], (0.0, 0.0, -1.0), atol=1e-9)
