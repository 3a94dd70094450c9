"""fovea_node: the instances of the current setting and the top-down fovea search.

Subscribes memory/blocks (transient local), camera/camera_info and camera/image_raw (sensor
data; the image is used only with mask_source "image"). Serves fovea/observe (every distinct
state-action pair of the setting, in scan order) and fovea/find_placement (a fovea location
realising a planned pair). Publishes fovea/markers: the fovea squares of the last answer.
"""

from __future__ import annotations

import colorsys
import math
import sys

import numpy as np
from geometry_msgs.msg import Point
from katana_common.futures import NumberedArrivals
from katana_common.node_runner import run_node
from katana_common.params import Param, declare_parameters
from katana_common.qos import SENSOR_QOS, STATE_QOS
from katana_common.scene import SCENE_PARAMS
from katana_interfaces.msg import BlockArray
from katana_interfaces.srv import FindPlacement, ObserveSetting
from katana_manipulation.core.reach import place_reach_table
from katana_manipulation.reach_params import REACH_PARAMS, reach_geometry
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from .core.fovea import N_ACTIONS, FoveaParams, FoveaScene, Instance, NotFound
from .messages import (
    blocks_from_msg,
    decode_or_warn,
    image_to_rgb,
    instance_to_msg,
    node_calibration,
)
from .perception_params import (
    BLOCKS_WAIT,
    COLOR_TABLE,
    EXTRINSICS_FILE,
    check_files_and_colors,
    missing_blocks,
    segmenter_from,
)

PARAMS = (
    *SCENE_PARAMS, *REACH_PARAMS, EXTRINSICS_FILE,
    Param("fovea_size_px", 40, "Fovea window edge, px.", 4, 200),
    Param("point_offset_px", 10.0, "r: the outer test points sit at (+-r, +-r) px.", 0.5, 99.0),
    Param("grid_step_px", 6.0, "Fovea grid step around a stack top, px.", 0.5, 100.0),
    Param("grid_radius_px", 36.0, "Fovea grid half-width around a stack top, px.", 0.0, 200.0),
    Param("fine_step_px", 2.0, "find_placement's second, finer grid step, px.", 0.5, 100.0),
    Param("table_step_m", 0.02, "Grid of candidate table places, m.", 0.002, 0.2),
    Param("play_x", [0.14, 0.30], "Play area x interval, m.", -2.0, 2.0, length=2),
    Param("play_y", [-0.16, 0.16], "Play area y interval, m.", -2.0, 2.0, length=2),
    Param("clearance", 0.005, "Free margin around a placed block, m.", 0.0, 0.1),
    Param("max_height", 3, "Highest stack offered for placement.", 0, 32),
    Param("table_yaw", 0.0, "Yaw of blocks placed on the table, rad.", -math.pi, math.pi),
    BLOCKS_WAIT,
    Param("mask_source", "memory", "'memory': block pixels are the remembered top faces "
          "re-projected; 'image': visible top blocks use their segmented pixels.",
          choices=("memory", "image")),
    COLOR_TABLE,
)


def _fovea_params(p) -> FoveaParams:
    """Fovea settings; the reach per stack height comes from the arm's kinematics and the
    executor's pick-and-place geometry (REACH_PARAMS, set for every node under `/**`)."""
    bands = place_reach_table(p["max_height"], p["block_size"][2], geometry=reach_geometry(p))
    return FoveaParams(
        size_px=p["fovea_size_px"], offset_px=p["point_offset_px"],
        grid_step_px=p["grid_step_px"], grid_radius_px=p["grid_radius_px"],
        fine_step_px=p["fine_step_px"], table_step_m=p["table_step_m"],
        reach_by_height=tuple((b.min_m, b.max_m) for b in bands if not b.empty),
        area_x=tuple(p["play_x"]), area_y=tuple(p["play_y"]), clearance=p["clearance"],
        max_height=p["max_height"], table_yaw=p["table_yaw"])


def cross_check(values) -> str | None:
    """The shared files and colours, and the fovea settings they give (start-up and live)."""
    problem = check_files_and_colors(values)
    if problem:
        return problem
    try:
        _fovea_params(values).validate()
    except ValueError as err:
        return str(err)
    return None


class FoveaNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("fovea_node", **kwargs)
        self.params = declare_parameters(self, PARAMS, cross_check)
        p = self.params
        self.world_frame = p["world_frame"]
        self.block_size = tuple(p["block_size"])
        self.fovea = _fovea_params(p)
        self.mask_source = p["mask_source"]
        self.segmenter = segmenter_from(p)
        self.get_logger().info("placement reach per stack height (kinematics): " + ", ".join(
            f"{s}: {lo:.3f}..{hi:.3f} m" for s, (lo, hi) in enumerate(self.fovea.reach_by_height)))

        self.calibration = None
        self.blocks = None
        self.blocks_arrivals = NumberedArrivals()  # BlockArray.sequence of `blocks`
        self.rgb = None
        self.setting = 0
        self._key = None
        self._scene: FoveaScene | None = None
        self.pub_markers = self.create_publisher(MarkerArray, "fovea/markers", STATE_QOS)
        self.create_subscription(BlockArray, "memory/blocks", self.on_blocks, STATE_QOS)
        self.create_subscription(CameraInfo, "camera/camera_info", self.on_camera_info,
                                 SENSOR_QOS)
        if self.mask_source == "image":  # read-only: no image traffic unless it is used
            self.create_subscription(Image, "camera/image_raw", self.on_image, SENSOR_QOS)
        # The services apart from the subscriptions, so that a burst of input callbacks cannot
        # hold an experiment's observe back; one group, so the two services never interleave.
        services = MutuallyExclusiveCallbackGroup()
        self.create_service(ObserveSetting, "fovea/observe", self.on_observe,
                            callback_group=services)
        self.create_service(FindPlacement, "fovea/find_placement", self.on_find,
                            callback_group=services)

    # ------------------------------------------------------------------ inputs
    def on_camera_info(self, msg: CameraInfo) -> None:
        calib = node_calibration(self, msg)
        if calib is not None:
            self.calibration = calib

    def on_image(self, msg: Image) -> None:
        rgb = decode_or_warn(self, "image", image_to_rgb, msg)
        if rgb is not None:
            self.rgb = rgb

    def on_blocks(self, msg: BlockArray) -> None:
        blocks = decode_or_warn(self, "memory/blocks", blocks_from_msg, msg)
        if blocks is None:
            return
        key = sorted((b.id, b.level, b.support, b.upright) for b in blocks)
        poses = {b.id: (b.x, b.y) for b in blocks}
        if self._key is None or key != self._key[0] or any(
            math.hypot(x - self._key[1][i][0], y - self._key[1][i][1]) > 0.003
            for i, (x, y) in poses.items()
        ):
            self.setting += 1
            self._key = (key, poses)
            self._scene = None
        self.blocks = blocks
        self.blocks_arrivals.arrived(msg.sequence)

    def _await_blocks(self, sequence: int) -> None:
        """Until the memory/blocks numbered `sequence` (or a later one) is in: the asker waited
        for it, and this node's subscription may not have taken it in yet. NotFound after
        blocks_wait_s."""
        why = missing_blocks(self.blocks_arrivals, sequence, self.params)
        if why:
            raise NotFound(why)

    # ------------------------------------------------------------------ services
    def _current_scene(self) -> FoveaScene:
        if self.blocks is None:
            raise NotFound("no memory/blocks received yet")
        if self.calibration is None:
            raise NotFound("no camera/camera_info received yet")
        if self._scene is None or self.mask_source == "image":
            masks = None
            if self.mask_source == "image":
                if self.rgb is None:
                    raise NotFound("mask_source is 'image' but no image received yet")
                on_top = {b.id for b in self.blocks if b.on_top}
                dets = self.segmenter.segment(self.rgb, self.calibration,
                                              {b.id: b.level for b in self.blocks})
                masks = {d.color: d.full_mask(self.rgb.shape[:2])
                         for d in dets if d.complete and d.color in on_top}
            self._scene = FoveaScene(self.blocks, self.calibration, self.fovea, masks)
        return self._scene

    def on_observe(self, req: ObserveSetting.Request, res: ObserveSetting.Response):
        try:
            self._await_blocks(int(req.blocks_sequence))
            insts = self._current_scene().observe(max_height=int(req.max_height))
        except NotFound as err:
            res.success, res.message = False, str(err)
            return res
        except Exception as err:  # a bug must not end the node: answer, and say so
            res.success, res.message = False, f"internal error: {err!r}"
            self.get_logger().error(f"observe: {err!r}")
            return res
        res.success = True
        res.setting = self.setting
        res.instances = [instance_to_msg(i) for i in insts]
        res.message = (f"{len(insts)} instances over states "
                       f"{sorted({i.state for i in insts})}")
        self.publish_markers(insts)
        return res

    def on_find(self, req: FindPlacement.Request, res: FindPlacement.Response):
        if not (0 <= req.state <= self.fovea.max_height and 1 <= req.action <= N_ACTIONS):
            res.found = False
            res.message = (f"no placement for stack height {req.state}, action {req.action}: "
                           f"state must be in 0..{self.fovea.max_height} (max_height), action "
                           f"in 1..{N_ACTIONS}")
            return res
        try:
            self._await_blocks(int(req.blocks_sequence))
            inst = self._current_scene().find(int(req.state), int(req.action))
        except NotFound as err:
            res.found, res.message = False, str(err)
            self.get_logger().info(f"find_placement({req.state}, {req.action}): {err}")
            return res
        except Exception as err:  # a bug must not end the node: answer, and say so
            res.found, res.message = False, f"internal error: {err!r}"
            self.get_logger().error(f"find_placement({req.state}, {req.action}): {err!r}")
            return res
        res.found, res.message, res.instance = True, "found", instance_to_msg(inst)
        self.publish_markers([inst])
        return res

    # ------------------------------------------------------------------ markers
    def publish_markers(self, insts: list[Instance]) -> None:
        if self.pub_markers.get_subscription_count() == 0 or self.calibration is None:
            return
        header = Header(frame_id=self.world_frame, stamp=self.get_clock().now().to_msg())
        out = MarkerArray(markers=[Marker(header=header, ns="fovea", action=Marker.DELETEALL)])
        half = self.fovea.size_px / 2.0
        h = self.block_size[2]
        for k, inst in enumerate(insts):
            c, s = math.cos(inst.angle), math.sin(inst.angle)
            corners = np.array([[-half, -half], [half, -half], [half, half], [-half, half],
                                [-half, -half]])
            us = inst.u + corners[:, 0] * c - corners[:, 1] * s
            vs = inst.v + corners[:, 0] * s + corners[:, 1] * c
            z = inst.state * h + 0.001
            xs, ys = self.calibration.pixel_to_world(us, vs, np.full(len(us), z))
            r, g, b = colorsys.hsv_to_rgb((inst.action - 1) / N_ACTIONS, 0.9, 1.0)
            colour = ColorRGBA(r=r, g=g, b=b, a=1.0)
            square = Marker(header=header, ns="fovea", id=2 * k, type=Marker.LINE_STRIP,
                            action=Marker.ADD, color=colour)
            square.scale.x = 0.001
            square.pose.orientation.w = 1.0
            square.points = [Point(x=float(x), y=float(y), z=z) for x, y in zip(xs, ys,
                                                                                 strict=True)]
            text = Marker(header=header, ns="fovea", id=2 * k + 1, type=Marker.TEXT_VIEW_FACING,
                          action=Marker.ADD, color=colour, text=f"s{inst.state} a{inst.action}")
            text.scale.z = 0.008
            text.pose.position.x, text.pose.position.y = inst.x, inst.y
            text.pose.position.z = inst.z + 0.02
            text.pose.orientation.w = 1.0
            out.markers += [square, text]
        self.pub_markers.publish(out)


def main(args: list[str] | None = None) -> int:
    return run_node(FoveaNode, "fovea_node", args)


if __name__ == "__main__":
    sys.exit(main())
