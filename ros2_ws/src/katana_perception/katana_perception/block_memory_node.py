"""block_memory_node: every block, occluded ones included, with stack levels.

Subscribes perception/detections (what the camera sees now), curiosity/experience (where an
experiment put a block and whether it stayed) and camera/camera_info (to locate a seen block
on the plane of its remembered level). Publishes world/blocks (transient local) after every
detection frame and every experience, stamped with the image time it reflects.
"""

from __future__ import annotations

import math

from katana_interfaces.msg import BlockArray, Experience
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import Header

from .conversions import blocks_to_msg, calibration_from_camera_info, seen_from_msg, yaw_of
from .core.memory import BlockMemory, MemoryParams
from .params import STATE_QOS, declare, declare_scene, run_node


class BlockMemoryNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("block_memory_node", **kwargs)
        scene = declare_scene(self)
        self.world_frame = scene["world_frame"]
        self.block_size = tuple(scene["block_size"])
        self.camera_position = scene["camera_position"]
        self.camera_rpy = scene["camera_rpy"]
        self.extrinsics_file = scene["extrinsics_file"]
        self.params = MemoryParams(
            position_tolerance=declare(
                self, "position_tolerance", 0.015,
                "A block seen farther than this from where it was remembered has moved, m "
                "(0.001..0.2).", 0.001, 0.2),
            occluded_tolerance=declare(
                self, "occluded_tolerance", 0.025,
                "The same for a block seen only in part, m (0.001..0.2).", 0.001, 0.2),
            cover_fraction=declare(
                self, "cover_fraction", 0.25,
                "Footprint overlap (share of a block) that puts one block on another "
                "(0.01..1).", 0.01, 1.0),
            forget_after=declare(
                self, "forget_after", 0,
                "Forget a block neither seen nor covered for this many frames; 0 = never "
                "(0..100000).", 0, 100000),
        )
        self.memory: BlockMemory | None = None
        self.last_stamp = None
        self.pub = self.create_publisher(BlockArray, "world/blocks", STATE_QOS)
        self.create_subscription(BlockArray, "perception/detections", self.on_detections, 10)
        self.create_subscription(Experience, "curiosity/experience", self.on_experience, 10)
        self.create_subscription(CameraInfo, "camera/camera_info", self.on_camera_info,
                                 qos_profile_sensor_data)

    def on_camera_info(self, msg: CameraInfo) -> None:
        try:
            calib = calibration_from_camera_info(msg, self.camera_position, self.camera_rpy,
                                                 self.extrinsics_file)
        except ValueError as err:
            self.get_logger().warn(f"camera_info rejected: {err}", throttle_duration_sec=5.0)
            return
        if self.memory is None:
            self.memory = BlockMemory(calib, self.params, self.block_size)
        else:
            self.memory.calibration = calib

    def on_detections(self, msg: BlockArray) -> None:
        if self.memory is None:
            self.get_logger().info("waiting for camera/camera_info", throttle_duration_sec=10.0)
            return
        if msg.header.frame_id and msg.header.frame_id != self.world_frame:
            self.get_logger().warn(f"detections rejected: frame {msg.header.frame_id!r}, "
                                   f"expected {self.world_frame!r}", throttle_duration_sec=5.0)
            return
        seen = []
        for b in msg.blocks:
            try:
                seen.append(seen_from_msg(b))
            except ValueError as err:
                self.get_logger().warn(f"detection ignored: {err}", throttle_duration_sec=5.0)
        if len({s.id for s in seen}) != len(seen):
            self.get_logger().warn("detections rejected: the same block id twice",
                                   throttle_duration_sec=5.0)
            return
        events = self.memory.update(seen)
        for bid, what in events.items():
            if what not in ("missing",):
                self.get_logger().info(f"{bid}: {what}")
        self.last_stamp = msg.header.stamp
        self.publish()

    def on_experience(self, msg: Experience) -> None:
        if self.memory is None:
            self.get_logger().warn("experience before any camera_info: ignored")
            return
        if msg.label not in (-1, 1):
            self.get_logger().warn(f"experience rejected: label {msg.label} is not +1 or -1")
            return
        p = msg.instance.placement
        if not (math.isfinite(p.position.x) and math.isfinite(p.position.y)):
            self.get_logger().warn("experience rejected: placement is not finite")
            return
        note = self.memory.apply_experience(
            msg.moved_block, int(msg.label), list(msg.instance.support_ids),
            (p.position.x, p.position.y), yaw_of(p),
        )
        self.get_logger().info(f"experience {msg.index}: {note}")
        self.publish()

    def publish(self) -> None:
        header = Header(frame_id=self.world_frame)
        if self.last_stamp is not None:
            header.stamp = self.last_stamp
        else:
            header.stamp = self.get_clock().now().to_msg()
        self.pub.publish(blocks_to_msg(self.memory.snapshot(), header))


def main(args: list[str] | None = None) -> None:
    run_node(BlockMemoryNode, "block_memory_node", SingleThreadedExecutor, args)


if __name__ == "__main__":
    main()
