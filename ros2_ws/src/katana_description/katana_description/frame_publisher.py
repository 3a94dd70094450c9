"""frame_publisher: the frame tree of the graph, so that RViz and Foxglove show the arm, the
camera image, the blocks and the fovea together.

A stand-in for robot_state_publisher (not on PyPI) with its topics and QoS, so that a full
install can run either (launch/sim.launch.py frames:=katana|robot_state_publisher):
- robot_description (std_msgs/String, ROBOT_DESCRIPTION_QOS): the URDF of `model`, the file the
  simulation loads (katana_description/urdf/katana_<model>.urdf);
- /tf (tf2_msgs/TFMessage, TF_QOS): the child link of every moving joint named in a
  joint_states message (JOINT_STATE_QOS), stamped with that message's stamp;
- /tf_static (TF_STATIC_QOS): once, in one message, the URDF's fixed joints and the scene's
  frames: world -> katana_base_link (the arm stands at the world origin: the simulation loads
  it there and the kinematics plan in the world frame) and world -> camera_link ->
  camera_optical_frame, the optical frame at the pose the perception uses (camera_position and
  camera_rpy, or the extrinsics_file that replaces them).
With robot_frames false it publishes only the scene's frames: beside robot_state_publisher.
"""

from __future__ import annotations

import sys

from builtin_interfaces.msg import Time
from geometry_msgs.msg import TransformStamped
from katana_common.node_runner import run_node
from katana_common.params import Param, declare_parameters
from katana_common.qos import JOINT_STATE_QOS, ROBOT_DESCRIPTION_QOS, TF_QOS, TF_STATIC_QOS
from katana_common.scene import SCENE_PARAMS
from rclpy.node import Node
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from . import models, urdf_path
from .core.frame_tree import (
    Transform,
    UrdfTree,
    camera_rotation_from_rpy,
    load_extrinsics,
    scene_transforms,
)

PARAMS: tuple[Param, ...] = SCENE_PARAMS + (
    Param("model", models.DEFAULT_MODEL, "Katana type: the URDF published and moved "
          "(urdf/katana_<model>.urdf, as the simulation loads it).",
          choices=tuple(sorted(models.MODELS))),
    Param("robot_frames", True, "Publish robot_description and the arm's frames (false: only "
          "world -> arm base and the camera frames, beside robot_state_publisher)."),
    Param("extrinsics_file", "", "Extrinsics YAML written by katana-calibrate; when set it "
          "replaces camera_position and camera_rpy (read-only)."),
    Param("camera_frame", "camera_optical_frame", "Optical frame of the images (REP 103: z "
          "forward, x right, y down).", nonempty=True),
    Param("camera_link_frame", "camera_link", "Camera body frame (REP 103: x forward, y left, "
          "z up).", nonempty=True),
)


def cross_check(values) -> str | None:
    """The extrinsics file exists and is one (the perception nodes refuse a missing one too)."""
    path = values.get("extrinsics_file", "")
    if path:
        try:
            load_extrinsics(path)
        except ValueError as err:
            return f"parameter 'extrinsics_file': {err}"
    return None


def camera_pose(values) -> tuple[tuple[float, float, float], Rotation]:
    """The optical frame's pose in the world, chosen as the perception chooses it
    (katana_perception.messages.calibration_from_camera_info)."""
    if values["extrinsics_file"]:
        return load_extrinsics(values["extrinsics_file"])
    x, y, z = values["camera_position"]
    return (x, y, z), camera_rotation_from_rpy(values["camera_rpy"])


def transform_msg(t: Transform, stamp: Time) -> TransformStamped:
    msg = TransformStamped()
    msg.header.stamp = stamp
    msg.header.frame_id = t.parent
    msg.child_frame_id = t.child
    msg.transform.translation.x, msg.transform.translation.y, msg.transform.translation.z = (
        t.translation)
    q = t.quaternion_xyzw
    msg.transform.rotation.x, msg.transform.rotation.y = q[0], q[1]
    msg.transform.rotation.z, msg.transform.rotation.w = q[2], q[3]
    return msg


class FramePublisher(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("frame_publisher", **kwargs)
        self.params = p = declare_parameters(self, PARAMS, cross_check)
        self.urdf = urdf_path(f"katana_{p['model']}.urdf").read_text(encoding="utf-8")
        self.tree = UrdfTree(self.urdf)
        robot = p["robot_frames"]
        static = scene_transforms(p["world_frame"], self.tree.root, p["camera_link_frame"],
                                  p["camera_frame"], *camera_pose(p))
        if robot:
            static = [*self.tree.fixed_transforms(), *static]
            self.description_pub = self.create_publisher(String, "robot_description",
                                                         ROBOT_DESCRIPTION_QOS)
            self.description_pub.publish(String(data=self.urdf))
            self.tf_pub = self.create_publisher(TFMessage, "/tf", TF_QOS)
            self.create_subscription(JointState, "joint_states", self.on_joint_states,
                                     JOINT_STATE_QOS)
        # one message with every static transform: the topic keeps only the last (depth 1)
        self.static_pub = self.create_publisher(TFMessage, "/tf_static", TF_STATIC_QOS)
        now = self.get_clock().now().to_msg()
        self.static_pub.publish(TFMessage(transforms=[transform_msg(t, now) for t in static]))
        self.get_logger().info(
            f"{len(static)} static frames; "
            + (f"moving the {len(self.tree.moving_joints)} joints of katana_{p['model']}"
               if robot else "no robot frames (robot_frames false)"))

    def on_joint_states(self, msg: JointState) -> None:
        if len(msg.name) != len(msg.position):
            self.get_logger().warn(
                f"joint_states ignored: {len(msg.name)} names but {len(msg.position)} positions",
                throttle_duration_sec=5.0)
            return
        moving = self.tree.moving_transforms(dict(zip(msg.name, msg.position, strict=True)))
        if moving:
            self.tf_pub.publish(TFMessage(
                transforms=[transform_msg(t, msg.header.stamp) for t in moving]))


def main(args: list[str] | None = None) -> int:
    return run_node(FramePublisher, "frame_publisher", args)


if __name__ == "__main__":
    sys.exit(main())
