"""ROS messages of the simulated world, and goals from ROS messages (no node here)."""

from __future__ import annotations

import numpy as np
from control_msgs.action import FollowJointTrajectory, GripperCommand
from geometry_msgs.msg import Pose
from katana_common.messages import time_msg
from katana_description import models as m
from katana_interfaces.msg import Block, BlockArray
from sensor_msgs.msg import CameraInfo, Image, JointState


def joint_state_msg(sim) -> JointState:
    pos, vel, eff = sim.joint_state()
    msg = JointState()
    msg.header.stamp = time_msg(sim.time)
    msg.name = list(m.ALL_JOINTS)
    msg.position, msg.velocity, msg.effort = pos.tolist(), vel.tolist(), eff.tolist()
    return msg


def camera_info_msg(sim) -> CameraInfo:
    cam = sim.camera
    info = CameraInfo()
    info.header.stamp = time_msg(sim.time)
    info.header.frame_id = cam.frame_id
    info.width, info.height = cam.width, cam.height
    info.distortion_model = "plumb_bob"
    info.d = [0.0] * 5
    info.k = cam.K.ravel().tolist()
    info.r = np.eye(3).ravel().tolist()
    info.p = cam.P.ravel().tolist()
    return info


def image_msg(sim) -> Image:
    img = sim.render()
    msg = Image()
    msg.header.stamp = time_msg(sim.time)
    msg.header.frame_id = sim.camera.frame_id
    msg.height, msg.width = img.shape[:2]
    msg.encoding = "rgb8"
    msg.is_bigendian = 0
    msg.step = img.shape[1] * 3
    msg.data = img.tobytes()
    return msg


def ground_truth_msg(sim, frame_id: str) -> BlockArray:
    arr = BlockArray()
    arr.header.stamp = time_msg(sim.time)
    arr.header.frame_id = frame_id
    for b in sim.ground_truth():
        blk = Block()
        blk.id, blk.color = b.id, b.color
        pose = Pose()
        pose.position.x, pose.position.y, pose.position.z = b.position
        (pose.orientation.x, pose.orientation.y, pose.orientation.z,
         pose.orientation.w) = b.quaternion
        blk.pose = pose
        blk.size.x, blk.size.y, blk.size.z = b.size
        blk.yaw, blk.level, blk.on_top, blk.visible = b.yaw, b.level, b.on_top, b.visible
        blk.pixel_u, blk.pixel_v, blk.pixel_angle = b.pixel_u, b.pixel_v, b.pixel_angle
        arr.blocks.append(blk)
    return arr


def trajectory_feedback(sim, follower) -> FollowJointTrajectory.Feedback:
    desired, _ = follower.sample(sim.elapsed(follower))
    actual = sim.joint_state()[0][:5]
    fb = FollowJointTrajectory.Feedback()
    fb.header.stamp = time_msg(sim.time)
    fb.joint_names = follower.names
    fb.desired.positions = desired.tolist()
    fb.actual.positions = actual.tolist()
    fb.error.positions = (actual - desired).tolist()
    return fb


def gripper_feedback(sim, controller) -> GripperCommand.Feedback:
    pos = float(sim.joint_state()[0][5:].mean())
    return GripperCommand.Feedback(position=pos, effort=controller.effort)
