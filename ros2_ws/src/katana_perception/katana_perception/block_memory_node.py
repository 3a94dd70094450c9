"""block_memory_node: every block, occluded ones included, with stack levels.

Subscribes perception/detections (what the camera sees now; a frame located on the levels from
before the last experience is skipped), curiosity/experience (where an
experiment put a block and whether it stayed) and camera/camera_info (to locate a seen block
on the plane of its remembered level). Publishes memory/blocks (transient local) after every
detection frame and every experience, stamped with the image time it reflects and numbered with
the last experience handled, the version of its levels and the settled frames since the
experience (the learner's exact ordering: BlockArray.msg),
and the same as memory/markers (a box per block, for RViz and Foxglove).
"""

from __future__ import annotations

import math
import sys

from katana_common.node_runner import run_node
from katana_common.params import Param, declare_parameters
from katana_common.qos import EVENT_QOS, SENSOR_QOS, STATE_QOS
from katana_common.scene import SCENE_PARAMS
from katana_interfaces.msg import BlockArray, Experience
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import Header
from visualization_msgs.msg import MarkerArray

from .core.memory import BlockMemory, MemoryParams
from .messages import block_markers, blocks_to_msg, node_calibration, seen_from_msg, yaw_of
from .perception_params import EXTRINSICS_FILE, check_files_and_colors

#: experiences placing a block farther than this from the pan axis are refused, m
WORKSPACE_RADIUS_M = 1.0

PARAMS = (
    *SCENE_PARAMS, EXTRINSICS_FILE,
    Param("position_tolerance", 0.015, "A block seen farther than this from where it was "
          "remembered has moved, m (live).", 0.001, 0.2, live=True),
    Param("occluded_tolerance", 0.025, "The same for a block seen only in part, m (live).",
          0.001, 0.2, live=True),
    Param("cover_fraction", 0.25, "Footprint overlap (share of a block) that puts one block "
          "on another (live).", 0.01, 1.0, live=True),
    Param("forget_after", 0, "Forget a block neither seen nor covered for this many frames; "
          "0 = never (live).", 0, 100000, live=True),
)


class BlockMemoryNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("block_memory_node", **kwargs)
        self.params = declare_parameters(self, PARAMS, check_files_and_colors)
        self.world_frame = self.params["world_frame"]
        self.block_size = tuple(self.params["block_size"])
        self.memory_params = MemoryParams()
        self._apply({})
        self.params.on_change(self._apply)
        self.memory: BlockMemory | None = None
        self.last_stamp = None
        self.experience = -1  # index of the last curiosity/experience handled
        self.levels_version = 0  # counts experiences and changes of the remembered levels
        self.settled_frames = 0
        self.sequence = 0  # arrays published (BlockArray.sequence)
        self.pub = self.create_publisher(BlockArray, "memory/blocks", STATE_QOS)
        self.marker_pub = self.create_publisher(MarkerArray, "memory/markers", STATE_QOS)
        self.create_subscription(BlockArray, "perception/detections", self.on_detections,
                                 EVENT_QOS)
        self.create_subscription(Experience, "curiosity/experience", self.on_experience,
                                 EVENT_QOS)
        self.create_subscription(CameraInfo, "camera/camera_info", self.on_camera_info,
                                 SENSOR_QOS)

    def _apply(self, changed: dict) -> None:
        mp = self.memory_params  # shared with BlockMemory: a change applies from the next frame
        for name in ("position_tolerance", "occluded_tolerance", "cover_fraction",
                     "forget_after"):
            setattr(mp, name, self.params[name])

    def on_camera_info(self, msg: CameraInfo) -> None:
        calib = node_calibration(self, msg)
        if calib is None:
            return
        if self.memory is None:
            self.memory = BlockMemory(calib, self.memory_params, self.block_size)
        else:
            self.memory.calibration = calib

    def on_detections(self, msg: BlockArray) -> None:
        if self.memory is None:
            self.get_logger().info("waiting for camera/camera_info", throttle_duration_sec=10.0)
            return
        if msg.experience < self.experience:
            # located on the levels from before the last experience: a plane the moved block
            # no longer lies on; the next frame comes from the levels published since
            return
        if msg.header.frame_id and msg.header.frame_id != self.world_frame:
            self.get_logger().warn(f"detections rejected: frame {msg.header.frame_id!r}, "
                                   f"expected {self.world_frame!r}", throttle_duration_sec=5.0)
            return
        seen = []
        calib = self.memory.calibration
        for b in msg.blocks:
            try:
                s = seen_from_msg(b)
            except ValueError as err:
                self.get_logger().warn(f"detection ignored: {err}", throttle_duration_sec=5.0)
                continue
            if not (0.0 <= s.u <= calib.width and 0.0 <= s.v <= calib.height):
                self.get_logger().warn(f"detection ignored: {s.id!r} at pixel ({s.u:.4g}, "
                                       f"{s.v:.4g}) is outside the {calib.width}x"
                                       f"{calib.height} image", throttle_duration_sec=5.0)
                continue
            seen.append(s)
        if len({s.id for s in seen}) != len(seen):
            self.get_logger().warn("detections rejected: the same block id twice",
                                   throttle_duration_sec=5.0)
            return
        levels = self.memory.levels()
        events = self.memory.update(seen)
        for bid, what in events.items():
            if what not in ("missing",):
                self.get_logger().info(f"{bid}: {what}")
        self.last_stamp = msg.header.stamp
        if self.memory.levels() != levels:  # a block on another plane: locate again on it
            self.levels_version += 1
            self.settled_frames = 0
        elif msg.levels_version == self.levels_version:
            self.settled_frames += 1
        self.publish()

    def on_experience(self, msg: Experience) -> None:
        # handled, folded in or refused: a learner waiting for it must not wait in vain
        self.experience, self.settled_frames = int(msg.index), 0
        self.levels_version += 1
        if self.memory is None:
            self.get_logger().warn("experience before any camera_info: ignored")
            return
        if msg.label not in (-1, 1):
            self.get_logger().warn(f"experience rejected: label {msg.label} is not +1 or -1")
            return
        p = msg.instance.placement
        q = p.orientation
        if not all(math.isfinite(v) for v in (p.position.x, p.position.y, q.x, q.y, q.z, q.w)):
            self.get_logger().warn("experience rejected: placement is not finite")
            return
        if math.hypot(p.position.x, p.position.y) > WORKSPACE_RADIUS_M:
            self.get_logger().warn(f"experience rejected: placement more than "
                                   f"{WORKSPACE_RADIUS_M} m from the arm")
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
        blocks = self.memory.snapshot()
        bad = [b.id for b in blocks if not all(math.isfinite(v) for v in (b.x, b.y, b.z, b.yaw))]
        if bad:  # a bug upstream: say so, publish only what is sound
            self.get_logger().error(f"not published: non-finite pose of {bad}",
                                    throttle_duration_sec=5.0)
            blocks = [b for b in blocks if b.id not in bad]
        msg = blocks_to_msg(blocks, header)
        msg.experience, msg.levels_version = self.experience, self.levels_version
        msg.settled_frames = self.settled_frames
        self.sequence += 1
        msg.sequence = self.sequence
        self.pub.publish(msg)
        self.marker_pub.publish(block_markers(msg))


def main(args: list[str] | None = None) -> int:
    return run_node(BlockMemoryNode, "block_memory_node", args)


if __name__ == "__main__":
    sys.exit(main())
