"""Messages <-> core types. Imports message packages, never rclpy."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from typing import TypeVar

import numpy as np
from geometry_msgs.msg import Pose, Vector3
from katana_interfaces.msg import Block as BlockMsg
from katana_interfaces.msg import BlockArray, FoveaInstance
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from .core.calibration import Calibration, load_extrinsics_yaml
from .core.colors import NOMINAL_RGB
from .core.fovea import Instance
from .core.judge import Placement
from .core.memory import Block, Seen, footprint_overlap, top_height
from .core.segmentation import Detection, wrap_quarter

M = TypeVar("M")
T = TypeVar("T")

_CHANNELS = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4}


def image_to_rgb(msg: Image) -> np.ndarray:
    """sensor_msgs/Image -> HxWx3 uint8 RGB; ValueError says what is wrong with the message."""
    enc = msg.encoding.lower()
    if enc not in _CHANNELS:
        raise ValueError(f"unsupported encoding {msg.encoding!r} (want one of "
                         f"{', '.join(_CHANNELS)})")
    ch = _CHANNELS[enc]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if h <= 0 or w <= 0:
        raise ValueError(f"empty image {w}x{h}")
    if step < w * ch:
        raise ValueError(f"step {step} is shorter than a row ({w} px x {ch} bytes)")
    data = np.frombuffer(msg.data, dtype=np.uint8)  # bytes, array.array or memoryview
    if data.size != step * h:
        raise ValueError(f"data has {data.size} bytes, expected step x height = {step * h}")
    rows = data.reshape(h, step)[:, : w * ch].reshape(h, w, ch)
    if enc == "rgb8":
        return np.ascontiguousarray(rows)
    if enc == "rgba8":
        return np.ascontiguousarray(rows[:, :, :3])
    return np.ascontiguousarray(rows[:, :, 2::-1])  # bgr8 / bgra8


def rgb_to_image(rgb: np.ndarray, header: Header) -> Image:
    msg = Image()
    msg.header = header
    msg.height, msg.width = int(rgb.shape[0]), int(rgb.shape[1])
    msg.encoding = "rgb8"
    msg.is_bigendian = 0
    msg.step = msg.width * 3
    msg.data = np.ascontiguousarray(rgb, dtype=np.uint8).tobytes()
    return msg


def calibration_from_camera_info(
    msg: CameraInfo, position: Sequence[float], rpy: Sequence[float], extrinsics_file: str = "",
) -> Calibration:
    """Intrinsics from CameraInfo, pose from the extrinsics file if given, else parameters;
    ValueError when a field is malformed or the whole is no camera over the table
    (`Calibration.implausibility`)."""
    k = list(msg.k)
    if len(k) != 9 or not all(math.isfinite(v) for v in k) or k[0] <= 0 or k[4] <= 0:
        raise ValueError(f"CameraInfo k is not a pinhole camera matrix: {k}")
    if msg.width <= 0 or msg.height <= 0:
        raise ValueError(f"CameraInfo has no image size ({msg.width}x{msg.height})")
    d = list(msg.d)
    if not all(math.isfinite(v) for v in d):
        raise ValueError(f"CameraInfo d (distortion) is not finite: {d}")
    if len(d) not in (0, 4, 5, 8, 12, 14):
        raise ValueError(f"CameraInfo d has {len(d)} coefficients; want 0, 4, 5, 8, 12 or 14")
    for name, values in (("p", msg.p), ("r", msg.r)):
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"CameraInfo {name} is not finite: {list(values)}")
    if msg.width > 20000 or msg.height > 20000:
        raise ValueError(f"CameraInfo image size {msg.width}x{msg.height} is implausible")
    K = np.asarray(k, dtype=float).reshape(3, 3)
    D = np.asarray(d, dtype=float) if d else np.zeros(5)
    if extrinsics_file:
        pos, quat = load_extrinsics_yaml(extrinsics_file)
        calibration = Calibration.from_camera_pose(K, pos, quat, msg.width, msg.height, D)
    else:
        calibration = Calibration.from_camera_rpy(K, position, rpy, msg.width, msg.height, D)
    problem = calibration.implausibility()
    if problem:
        raise ValueError(f"CameraInfo with this camera pose is not a camera over the table: "
                         f"{problem}")
    return calibration



def decode_or_warn(node, what: str, decode: Callable[[M], T], msg: M) -> T | None:
    """decode(msg); or, when that raises ValueError, None after a throttled warning on the
    node's logger that `what` was rejected and why (a bad message must not end a node)."""
    try:
        return decode(msg)
    except ValueError as err:
        node.get_logger().warn(f"{what} rejected: {err}", throttle_duration_sec=5.0)
        return None


def node_calibration(node, msg: CameraInfo) -> Calibration | None:
    """The calibration of a CameraInfo with the node's camera pose parameters (camera_position,
    camera_rpy, extrinsics_file), or None after a throttled warning saying why it was refused.

    A camera sends the same camera_info with every image: while it and the parameters stay
    the same, the node gets the same Calibration object back, so that what it computed with
    the calibration (the perception node's segmented frame) stays valid."""
    pose = (tuple(node.params["camera_position"]), tuple(node.params["camera_rpy"]),
            node.params["extrinsics_file"])
    key = (msg.width, msg.height, msg.distortion_model, tuple(msg.k), tuple(msg.d),
           tuple(msg.r), tuple(msg.p), pose)
    cached = getattr(node, "_calibration_from", None)
    if cached is not None and cached[0] == key:
        return cached[1]
    calib = decode_or_warn(node, "camera_info",
                           lambda m: calibration_from_camera_info(m, *pose), msg)
    if calib is not None:
        node._calibration_from = (key, calib)
    return calib


def yaw_quaternion(pose: Pose, yaw: float) -> None:
    pose.orientation.x = 0.0
    pose.orientation.y = 0.0
    pose.orientation.z = math.sin(yaw / 2.0)
    pose.orientation.w = math.cos(yaw / 2.0)


def yaw_of(pose: Pose) -> float:
    q = pose.orientation
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _size(size: Sequence[float]) -> Vector3:
    return Vector3(x=float(size[0]), y=float(size[1]), z=float(size[2]))


def detection_to_msg(d: Detection, calib: Calibration) -> BlockMsg:
    """A visible block, located at the level it was segmented with (1 unless memory knew),
    with its resting size: x along the reported yaw, z vertical (a block on its side is
    taller than a level)."""
    z_top = top_height(d.level, d.size)
    x, y = (float(a) for a in calib.pixel_to_world(d.u, d.v, z_top))
    edge_yaw = calib.image_angle_to_yaw(d.u, d.v, d.angle, z_top)
    yaw = wrap_quarter(edge_yaw)
    sx, sy, sz = d.size
    if round((edge_yaw - yaw) / (math.pi / 2)) % 2:  # yaw now runs along the other edge
        sx, sy = sy, sx
    b = BlockMsg(id=d.color, color=d.color, size=_size((sx, sy, sz)), yaw=yaw, level=d.level,
                 on_top=bool(d.complete), visible=True, pixel_u=d.u, pixel_v=d.v,
                 pixel_angle=d.angle)
    b.pose.position.x, b.pose.position.y, b.pose.position.z = x, y, z_top - sz / 2.0
    yaw_quaternion(b.pose, yaw)
    return b


def seen_from_msg(b: BlockMsg) -> Seen:
    vals = (b.pixel_u, b.pixel_v, b.pixel_angle)
    if not b.id or not all(math.isfinite(v) for v in vals):
        raise ValueError(f"detection {b.id!r} has no id or no pixel position/angle")
    size: tuple[float, float, float] | None = (b.size.x, b.size.y, b.size.z)
    if size == (0.0, 0.0, 0.0):
        size = None  # not measured: the nominal block
    elif not all(math.isfinite(v) and v > 0 for v in size):
        raise ValueError(f"detection {b.id!r} has size {size}")
    return Seen(b.id, b.color or b.id, float(b.pixel_u), float(b.pixel_v),
                float(b.pixel_angle), bool(b.on_top), size)


def block_to_msg(b: Block) -> BlockMsg:
    m = BlockMsg(id=b.id, color=b.color, size=_size(b.size), yaw=float(b.yaw),
                 level=int(b.level), on_top=bool(b.on_top), visible=bool(b.visible),
                 pixel_u=float(b.pixel_u), pixel_v=float(b.pixel_v),
                 pixel_angle=float(b.pixel_angle), resting_pose_known=bool(b.pose_known))
    m.pose.position.x, m.pose.position.y, m.pose.position.z = float(b.x), float(b.y), float(b.z)
    yaw_quaternion(m.pose, b.yaw)
    return m


def blocks_to_msg(blocks: Iterable[Block], header: Header) -> BlockArray:
    return BlockArray(header=header, blocks=[block_to_msg(b) for b in blocks])


def block_markers(msg: BlockArray) -> MarkerArray:
    """memory/blocks as RViz and Foxglove draw it: a box per block at its pose and size, in its
    colour (grey when the colour has no nominal one), and its id above it; the previous
    markers deleted first, so a block gone from memory goes from the view too."""
    out = MarkerArray(markers=[Marker(header=msg.header, ns="blocks", action=Marker.DELETEALL)])
    for k, b in enumerate(msg.blocks):
        r, g, bl = NOMINAL_RGB.get(b.color, (0.5, 0.5, 0.5))
        box = Marker(header=msg.header, ns="blocks", id=2 * k, type=Marker.CUBE,
                     action=Marker.ADD, pose=b.pose, color=ColorRGBA(r=r, g=g, b=bl, a=0.9))
        box.scale.x, box.scale.y, box.scale.z = b.size.x, b.size.y, b.size.z
        label = Marker(header=msg.header, ns="blocks", id=2 * k + 1,
                       type=Marker.TEXT_VIEW_FACING, action=Marker.ADD, text=b.id,
                       color=ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0))
        label.pose.position.x, label.pose.position.y = b.pose.position.x, b.pose.position.y
        label.pose.position.z = b.pose.position.z + b.size.z
        label.pose.orientation.w = 1.0
        label.scale.z = 0.012
        out.markers += [box, label]
    return out


def blocks_from_msg(msg: BlockArray) -> list[Block]:
    """memory/blocks -> memory blocks. The message has levels, not supports: a block at level
    L rests on the level L-1 block its footprint overlaps most (each block carries one)."""
    out = []
    for m in msg.blocks:
        if not m.id:
            raise ValueError("a block without an id")
        if m.level < 1:
            raise ValueError(f"block {m.id!r} has level {m.level}; levels start at 1")
        p = m.pose.position
        if not all(math.isfinite(v) for v in (p.x, p.y, m.yaw)):
            raise ValueError(f"block {m.id!r} has a non-finite pose")
        size = (m.size.x, m.size.y, m.size.z)
        if not all(math.isfinite(v) and v > 0 for v in size):
            raise ValueError(f"block {m.id!r} has size {size}")
        out.append(Block(m.id, m.color or m.id, p.x, p.y, m.yaw, level=int(m.level),
                         on_top=bool(m.on_top), visible=bool(m.visible), pixel_u=m.pixel_u,
                         pixel_v=m.pixel_v, pixel_angle=m.pixel_angle, size=size,
                         pose_known=bool(m.resting_pose_known)))
    if len({b.id for b in out}) != len(out):
        raise ValueError("duplicate block ids")
    carried: set[str] = set()
    for b in sorted(out, key=lambda b: (b.level, b.id)):
        if b.level == 1:
            continue
        below = [o for o in out if o.level == b.level - 1 and o.id not in carried]
        if not below:
            raise ValueError(f"block {b.id!r} at level {b.level} has nothing to rest on")
        best = max(below, key=lambda o: (footprint_overlap(b, o),
                                         -math.hypot(o.x - b.x, o.y - b.y)))
        b.support = best.id
        carried.add(best.id)
    return out


def instance_to_msg(inst: Instance) -> FoveaInstance:
    m = FoveaInstance(state=int(inst.state), action=int(inst.action),
                      features=[float(v) for v in inst.features], bits=[bool(b) for b in inst.bits],
                      pixel_u=float(inst.u), pixel_v=float(inst.v),
                      support_ids=list(inst.support_ids))
    m.placement.position.x, m.placement.position.y = float(inst.x), float(inst.y)
    m.placement.position.z = float(inst.z)
    yaw_quaternion(m.placement, inst.yaw)
    return m


def placement_from_msg(m: FoveaInstance) -> Placement:
    p = m.placement.position
    if not (math.isfinite(p.x) and math.isfinite(p.y)):
        raise ValueError("the instance's placement is not a finite point")
    return Placement(int(m.state), float(p.x), float(p.y), tuple(m.support_ids))
