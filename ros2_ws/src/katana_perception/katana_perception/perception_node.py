"""perception_node: overhead image -> visible blocks; the placement outcome judge.

Subscribes camera/image_raw and camera/camera_info (sensor-data QoS) and memory/blocks
(transient local: the remembered levels, so a block on a stack is located on the right
plane, and the "before" memory of the judge). Publishes perception/detections
(katana_interfaces/BlockArray of the blocks seen in the image; `on_top` means its top face is
in full view, `level` is the level it was located at; `experience` is that of the memory/blocks
the levels came from) and perception/debug_image. Serves
perception/judge_placement: PHASE_BEFORE keeps the current image and memory, PHASE_AFTER
judges the newest image against them.
"""

from __future__ import annotations

import math
import sys
import threading

import cv2
import numpy as np
from katana_common.diagnostics import Diagnostics
from katana_common.executor import MultiThreadedExecutor
from katana_common.futures import NumberedArrivals
from katana_common.health import RateMeter, stream_health
from katana_common.node_runner import run_node
from katana_common.params import Param, declare_parameters
from katana_common.qos import EVENT_QOS, SENSOR_QOS, STATE_QOS
from katana_common.scene import SCENE_PARAMS
from katana_interfaces.msg import BlockArray
from katana_interfaces.srv import JudgePlacement
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header

from .core.judge import Judge, JudgeParams
from .messages import (
    blocks_from_msg,
    decode_or_warn,
    detection_to_msg,
    image_to_rgb,
    node_calibration,
    placement_from_msg,
    rgb_to_image,
)
from .perception_params import (
    BLOCKS_WAIT,
    COLOR_TABLE,
    EXTRINSICS_FILE,
    check_files_and_colors,
    missing_blocks,
    segmenter_from,
)

#: placements the judge accepts: within this distance of the pan axis, below this height, m
WORKSPACE_RADIUS_M = 1.0
WORKSPACE_TOP_M = 1.0

PARAMS = (
    *SCENE_PARAMS, EXTRINSICS_FILE, COLOR_TABLE,
    Param("saturation_min", 80, "Minimum HSV saturation of a block pixel (live).", 0, 255,
          live=True),
    Param("value_min", 40, "Minimum HSV value of a block pixel (live).", 0, 255, live=True),
    Param("min_area_px", 120, "Smallest blob taken for a block, px (live).", 1, 100000,
          live=True),
    Param("min_inscribed_px", 6.0, "A blob must contain a disc of this radius, px; thinner "
          "ones are side faces of covered blocks (live).", 0.0, 100.0, live=True),
    Param("occlusion_threshold", 0.04, "Share of a top face covered by other colours above "
          "which a block counts as covered (live).", 0.0, 1.0, live=True),
    Param("position_tolerance", 0.015, "Judge: placed block centre vs placement point, m "
          "(live).", 0.001, 0.1, live=True),
    Param("support_tolerance", 0.006, "Judge: how far a partly seen support block's pixels "
          "may lie outside where it was, m (live).", 0.001, 0.1, live=True),
    Param("changed_fraction", 0.15, "Judge: share of the stack's former pixels that may "
          "change (live).", 0.0, 1.0, live=True),
    Param("publish_debug_image", True, "Publish perception/debug_image when someone listens "
          "(live).", live=True),
    BLOCKS_WAIT,
)


class PerceptionNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("perception_node", **kwargs)
        self.params = declare_parameters(self, PARAMS, check_files_and_colors)
        self.world_frame = self.params["world_frame"]
        self.segmenter = segmenter_from(self.params)
        self._segmented: tuple | None = None  # (calibration, levels, blocks) of the last frame
        self._apply(dict(self.params))
        self.params.on_change(self._apply)

        self.calibration = None
        self.levels: dict[str, int] = {}
        self.levels_experience = -1  # memory/blocks' experience the levels come from
        self.levels_version = 0  # ... and the version of those levels
        self.memory_blocks = []
        self.blocks_arrivals = NumberedArrivals()  # BlockArray.sequence of memory_blocks
        self.latest_rgb: np.ndarray | None = None
        self.latest_header: Header | None = None  # the latest image's
        self.frames = 0
        self.before = None  # (snapshot, frame number)

        self.pub_detections = self.create_publisher(BlockArray, "perception/detections",
                                                    EVENT_QOS)
        self.pub_debug = self.create_publisher(Image, "perception/debug_image", SENSOR_QOS)
        self.images = RateMeter(window_s=10.0)
        self.diagnostics = Diagnostics(
            self, {"camera": lambda: stream_health("images", self.images)})
        # Images in one group, camera_info and memory/blocks in another: a camera faster than
        # segmentation keeps the image subscription ready, and in one group with it they would
        # lose every race for the group to it (never calibrated, or judging from an old memory).
        # Their callbacks share the node's state under `_state_lock`.
        self._state_lock = threading.Lock()
        self.create_subscription(Image, "camera/image_raw", self.on_image, SENSOR_QOS)
        state = MutuallyExclusiveCallbackGroup()
        self.create_subscription(CameraInfo, "camera/camera_info", self.on_camera_info,
                                 SENSOR_QOS, callback_group=state)
        self.create_subscription(BlockArray, "memory/blocks", self.on_memory_blocks, STATE_QOS,
                                 callback_group=state)
        # own group: a camera faster than segmentation keeps the image subscription ready, and
        # rclpy serves subscriptions first, so the judge starved behind frames (hardware graph)
        self.create_service(JudgePlacement, "perception/judge_placement", self.on_judge,
                            callback_group=MutuallyExclusiveCallbackGroup())

    def _apply(self, changed: dict) -> None:
        """Segmentation and judge settings, at start-up and on a live change."""
        p, seg = self.params, self.segmenter
        self._segmented = None  # new settings: the next frame is segmented anew
        seg.s_min, seg.v_min = int(p["saturation_min"]), int(p["value_min"])
        seg.min_area_px = int(p["min_area_px"])
        seg.min_inscribed_px = float(p["min_inscribed_px"])
        seg.occlusion_threshold = float(p["occlusion_threshold"])
        self.judge_params = JudgeParams(position_tolerance=p["position_tolerance"],
                                        support_tolerance=p["support_tolerance"],
                                        changed_fraction=p["changed_fraction"])
        self.publish_debug = bool(p["publish_debug_image"])

    # ------------------------------------------------------------------ inputs
    def on_camera_info(self, msg: CameraInfo) -> None:
        calib = node_calibration(self, msg)
        if calib is None:
            return
        if self.calibration is None:
            self.get_logger().info(f"calibrated: {calib.width}x{calib.height}, "
                                   f"fx {calib.K[0, 0]:.1f}, camera at {calib.centre.round(3)}")
        with self._state_lock:
            self.calibration = calib

    def on_memory_blocks(self, msg: BlockArray) -> None:
        blocks = decode_or_warn(self, "memory/blocks", blocks_from_msg, msg)
        if blocks is None:
            return
        with self._state_lock:
            self.memory_blocks = blocks
            self.levels = {b.id: b.level for b in blocks}
            changed = msg.levels_version != self.levels_version
            self.levels_experience = int(msg.experience)
            self.levels_version = int(msg.levels_version)
            if changed and self.latest_rgb is not None and self.calibration is not None:
                # The memory has folded an experience in or changed a level and waits for a
                # frame located on its new levels: the latest image, segmented on them, is that
                # frame (no wait for the next image; the scene is the one it shows).
                self._publish_detections(self.latest_rgb, self.latest_header, self.latest_rgb)
            self.blocks_arrivals.arrived(msg.sequence)

    def on_image(self, msg: Image) -> None:
        self.images.tick()
        rgb = decode_or_warn(self, "image", image_to_rgb, msg)
        if rgb is None:
            return
        with self._state_lock:
            calib = self.calibration
            if calib is None:
                self.get_logger().info("waiting for camera/camera_info",
                                       throttle_duration_sec=10.0)
                return
            if rgb.shape[:2] != (calib.height, calib.width):
                self.get_logger().warn(
                    f"image rejected: {rgb.shape[1]}x{rgb.shape[0]} but camera_info says "
                    f"{calib.width}x{calib.height}", throttle_duration_sec=5.0)
                return
            previous = self.latest_rgb
            self.latest_rgb, self.latest_header = rgb, msg.header
            self.frames += 1
            self._publish_detections(rgb, msg.header, previous)

    def _publish_detections(self, rgb: np.ndarray, image_header: Header, previous) -> None:
        """perception/detections of `rgb` on the current levels, stamped with its image (under
        `_state_lock`)."""
        # A still scene seen by a still camera (the simulator between motions) repeats its
        # frame exactly: the same pixels and levels segment to the same blocks.
        calib, levels, dets = self._segmented or (None, None, None)
        if not (calib is self.calibration and levels == self.levels
                and (previous is rgb or np.array_equal(previous, rgb))):
            dets = self.segmenter.segment(rgb, self.calibration, self.levels)
            self._segmented = (self.calibration, dict(self.levels), dets)
        header = Header(stamp=image_header.stamp, frame_id=self.world_frame)
        out = BlockArray(header=header,
                         blocks=[detection_to_msg(d, self.calibration)
                                 for d in dets], experience=self.levels_experience,
                         levels_version=self.levels_version)
        self.pub_detections.publish(out)
        if self.publish_debug and self.pub_debug.get_subscription_count() > 0:
            self.pub_debug.publish(rgb_to_image(self._draw(rgb, dets), image_header))

    def _draw(self, rgb: np.ndarray, dets) -> np.ndarray:
        img = rgb.copy()
        for d in dets:
            box = cv2.boxPoints(((d.u, d.v), (d.top_px, d.top_px), np.rad2deg(d.angle)))
            colour = (255, 255, 255) if d.complete else (40, 40, 40)
            cv2.polylines(img, [np.rint(box).astype(np.int32)], True, colour, 1, cv2.LINE_AA)
            cv2.circle(img, (int(round(d.u)), int(round(d.v))), 2, colour, -1)
            cv2.putText(img, f"{d.color} L{d.level}", (int(d.u) + 6, int(d.v) - 6),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.35, colour, 1, cv2.LINE_AA)
        return img

    # ------------------------------------------------------------------ judge
    def _instance_problem(self, inst) -> str | None:
        """Why a PHASE_AFTER instance cannot be judged (None when it can)."""
        p = inst.placement.position
        if not all(math.isfinite(v) for v in (p.x, p.y, p.z)):
            return "the instance's placement is not a finite point"
        if math.hypot(p.x, p.y) > WORKSPACE_RADIUS_M or not -0.01 <= p.z <= WORKSPACE_TOP_M:
            return (f"placement ({p.x:.3g}, {p.y:.3g}, {p.z:.3g}) m is outside the workspace "
                    f"(radius <= {WORKSPACE_RADIUS_M} m, 0 <= z <= {WORKSPACE_TOP_M} m)")
        names = self.segmenter.names
        if not 0 <= inst.state < len(names):
            return f"state {inst.state} is outside 0..{len(names) - 1} (stack heights)"
        unknown = [b for b in inst.support_ids if b not in names]
        if unknown:
            return f"support ids {unknown} are not in the colour table ({', '.join(names)})"
        if len(inst.support_ids) != inst.state:
            return (f"state {inst.state} needs {inst.state} support ids, got "
                    f"{len(inst.support_ids)}")
        return None

    def on_judge(self, req: JudgePlacement.Request, res: JudgePlacement.Response):
        try:
            return self._judge(req, res)
        except Exception as err:  # a bug must not end the node: answer, and say so
            self.get_logger().error(f"judge_placement: {err!r}")
            res.success, res.label, res.message = False, 0, f"internal error: {err!r}"
            return res

    def _judge(self, req: JudgePlacement.Request, res: JudgePlacement.Response):
        res.label = 0
        before_phase = req.phase == JudgePlacement.Request.PHASE_BEFORE
        if not before_phase and req.phase != JudgePlacement.Request.PHASE_AFTER:
            res.success, res.message = False, f"unknown phase {req.phase} (0 before, 1 after)"
            return res
        placement = None
        if not before_phase:
            if req.placed_block not in self.segmenter.names:
                res.success = False
                res.message = (f"placed_block {req.placed_block!r} is not in the colour table "
                               f"({', '.join(self.segmenter.names)})")
                return res
            problem = self._instance_problem(req.instance)
            if problem:
                res.success, res.message = False, problem
                self.get_logger().warn(f"judge_placement refused: {problem}",
                                       throttle_duration_sec=2.0)
                return res
            placement = placement_from_msg(req.instance)
        # the memory the asker acted on, and so an image at least as new as the one it was
        # built from: what the judge sees then does not depend on thread timing
        why = missing_blocks(self.blocks_arrivals, req.blocks_sequence, self.params)
        if why:
            res.success, res.message = False, why
            return res
        with self._state_lock:
            rgb, calib, blocks, frames = (self.latest_rgb, self.calibration,
                                          self.memory_blocks, self.frames)
        if rgb is None or calib is None:
            res.success, res.message = False, "no image (or no camera_info) received yet"
            return res
        judge = Judge(self.segmenter, calib, self.judge_params)
        if before_phase:
            self.before = (judge.snapshot(rgb, blocks), frames)
            res.success, res.message = True, f"before: image {frames} kept"
            return res
        if self.before is None:
            res.success, res.message = False, "no PHASE_BEFORE snapshot to compare with"
            return res
        if frames <= self.before[1]:
            res.success, res.message = False, "no new image since PHASE_BEFORE"
            return res
        verdict = judge.judge(self.before[0], rgb, req.placed_block, placement)
        self.before = None
        res.success, res.label, res.message = True, int(verdict.label), verdict.reason
        self.get_logger().info(f"judged {'stable' if verdict.label > 0 else 'fell'}: "
                               f"{verdict.reason}")
        return res


def main(args: list[str] | None = None) -> int:
    return run_node(PerceptionNode, "perception_node", args,
                    executor_factory=MultiThreadedExecutor)


if __name__ == "__main__":
    sys.exit(main())
