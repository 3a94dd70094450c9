"""The frame tree frame_publisher publishes: the URDF's joints as transforms, and the scene's
world -> arm base and world -> camera frames. ROS-free (no messages: the node converts).

The URDF is parsed with the standard library's xml.etree: the venv has no maintained URDF
parser (urdf_parser_py and yourdfpy are not on it; PyBullet loads a URDF but hides the joint
origins behind its own link frames, which is why the tests use it as the independent check),
and the tree needs only five things of each joint: its type, parent, child, origin (xyz, rpy)
and axis (plus mimic, as robot_state_publisher honours it). Rotations are scipy's.

A transform here is "the pose of `child` in `parent`", as in a TF message: a point p in the
child frame is at R p + t in the parent frame.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

#: joint types whose child moves with a joint position (robot_state_publisher's /tf)
MOVING_TYPES = ("revolute", "continuous", "prismatic")
#: joint types published once, on /tf_static (robot_state_publisher skips floating joints;
#: planar ones have no single position either)
FIXED_TYPES = ("fixed",)

#: REP 103: the optical frame's axes (x right, y down, z forward) in camera_link's (x forward,
#: y left, z up). Columns: optical x = -y_link, optical y = -z_link, optical z = +x_link.
OPTICAL_IN_LINK = np.array([[0.0, 0.0, 1.0],
                            [-1.0, 0.0, 0.0],
                            [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class Transform:
    """Pose of `child` in `parent`: translation (m) and rotation (scipy)."""

    parent: str
    child: str
    translation: tuple[float, float, float]
    rotation: Rotation

    @property
    def quaternion_xyzw(self) -> tuple[float, float, float, float]:
        x, y, z, w = self.rotation.as_quat()
        return float(x), float(y), float(z), float(w)

    def matrix(self) -> np.ndarray:
        """4x4 homogeneous matrix (child coordinates -> parent coordinates)."""
        m = np.eye(4)
        m[:3, :3] = self.rotation.as_matrix()
        m[:3, 3] = self.translation
        return m


@dataclass(frozen=True)
class Joint:
    """The parts of a URDF joint the tree needs."""

    name: str
    type: str
    parent: str
    child: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    axis: tuple[float, float, float] = (1.0, 0.0, 0.0)  # URDF's default axis
    mimic: tuple[str, float, float] | None = None  # (joint, multiplier, offset)

    def transform(self, position: float = 0.0) -> Transform:
        """The child's pose in the parent at this joint position (rad or m)."""
        origin = Rotation.from_euler("xyz", self.rpy)  # URDF rpy: fixed axes x, y, z
        t = np.asarray(self.xyz, dtype=float)
        axis = np.asarray(self.axis, dtype=float)
        if self.type in ("revolute", "continuous"):
            rotation = origin * Rotation.from_rotvec(axis * position)
        else:
            rotation = origin
            if self.type == "prismatic":
                t = t + origin.apply(axis * position)
        return Transform(self.parent, self.child, _triple(t), rotation)


def _floats(text: str | None, default: tuple[float, float, float]) -> tuple[float, float, float]:
    if text is None:
        return default
    values = [float(v) for v in text.split()]
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise ValueError(f"URDF: '{text}' is not three finite numbers")
    return _triple(values)


def _triple(values: Iterable[float]) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in values)
    return x, y, z


class UrdfTree:
    """The joints of a URDF, and the transforms robot_state_publisher would publish."""

    def __init__(self, urdf_text: str) -> None:
        try:
            root = ET.fromstring(urdf_text)
        except ET.ParseError as err:
            raise ValueError(f"URDF is not XML: {err}") from None
        if root.tag != "robot":
            raise ValueError(f"URDF root element is <{root.tag}>, not <robot>")
        self.name = root.get("name", "")
        self.links = tuple(link.get("name", "") for link in root.findall("link"))
        joints = []
        for j in root.findall("joint"):
            origin, axis, mimic = j.find("origin"), j.find("axis"), j.find("mimic")
            parent, child = j.find("parent"), j.find("child")
            if parent is None or child is None:
                raise ValueError(f"URDF joint '{j.get('name')}' lacks a parent or a child")
            joints.append(Joint(
                name=j.get("name", ""), type=j.get("type", ""),
                parent=parent.get("link", ""), child=child.get("link", ""),
                xyz=_floats(None if origin is None else origin.get("xyz"), (0.0, 0.0, 0.0)),
                rpy=_floats(None if origin is None else origin.get("rpy"), (0.0, 0.0, 0.0)),
                axis=_floats(None if axis is None else axis.get("xyz"), (1.0, 0.0, 0.0)),
                mimic=None if mimic is None else (
                    mimic.get("joint", ""), float(mimic.get("multiplier", "1")),
                    float(mimic.get("offset", "0"))),
            ))
        self.joints: dict[str, Joint] = {j.name: j for j in joints}
        children = [j.child for j in joints]
        roots = [link for link in self.links if link not in children]
        if len(roots) != 1 or len(set(children)) != len(children):
            raise ValueError(f"URDF '{self.name}' is not a tree (roots {roots})")
        self.root = roots[0]

    @property
    def moving_joints(self) -> tuple[str, ...]:
        return tuple(n for n, j in self.joints.items() if j.type in MOVING_TYPES)

    def fixed_transforms(self) -> list[Transform]:
        """Every fixed joint's child in its parent (robot_state_publisher's /tf_static)."""
        return [j.transform() for j in self.joints.values() if j.type in FIXED_TYPES]

    def moving_transforms(self, positions: Mapping[str, float]) -> list[Transform]:
        """The child of every moving joint named in `positions` (or mimicking one that is),
        at that position (robot_state_publisher's /tf for one joint_states message)."""
        out = []
        for name, joint in self.joints.items():
            if joint.type not in MOVING_TYPES:
                continue
            if name in positions:
                q = float(positions[name])
            elif joint.mimic is not None and joint.mimic[0] in positions:
                q = float(positions[joint.mimic[0]]) * joint.mimic[1] + joint.mimic[2]
            else:
                continue
            out.append(joint.transform(q))
        return out


def pose_transform(parent: str, child: str, position: Sequence[float],
                   rotation: Rotation) -> Transform:
    return Transform(parent, child, _triple(position), rotation)


def scene_transforms(world_frame: str, base_frame: str, camera_link_frame: str,
                     camera_frame: str, camera_position: Sequence[float],
                     camera_rotation: Rotation) -> list[Transform]:
    """world -> arm base (identity: the simulation loads the arm at the world origin and the
    kinematics plan in the world frame) and world -> camera_link -> camera optical frame, for
    the optical frame at `camera_position` with `camera_rotation` in the world (the pose the
    perception's Calibration takes): camera_link shares the optical centre, turned by the
    fixed REP 103 rotation."""
    link_to_optical = Rotation.from_matrix(OPTICAL_IN_LINK)
    return [
        pose_transform(world_frame, base_frame, (0.0, 0.0, 0.0), Rotation.identity()),
        pose_transform(world_frame, camera_link_frame, camera_position,
                       camera_rotation * link_to_optical.inv()),
        pose_transform(camera_link_frame, camera_frame, (0.0, 0.0, 0.0), link_to_optical),
    ]


def camera_rotation_from_rpy(rpy: Sequence[float]) -> Rotation:
    """camera_rpy (fixed axes roll, pitch, yaw of the optical frame in the world) as a rotation,
    read as katana_perception's Calibration.from_camera_rpy reads it."""
    r = np.asarray(rpy, dtype=float)
    if r.shape != (3,) or not np.isfinite(r).all():
        raise ValueError(f"camera rpy must be three finite angles; got {list(rpy)}")
    return Rotation.from_euler("xyz", r)


def load_extrinsics(path: str) -> tuple[tuple[float, float, float], Rotation]:
    """The optical frame's pose in the world from an extrinsics YAML of katana-calibrate
    (translation x, y, z; rotation x, y, z, w), which the perception then uses instead of
    camera_position and camera_rpy."""
    try:
        with open(path, encoding="utf-8") as fh:
            data = yaml.safe_load(fh)
        t, r = data["translation"], data["rotation"]
        position = _triple((t["x"], t["y"], t["z"]))
        q = np.array([r["x"], r["y"], r["z"], r["w"]], dtype=float)
    except (OSError, KeyError, TypeError, yaml.YAMLError) as err:
        raise ValueError(f"{path}: not an extrinsics YAML ({err})") from None
    if not np.isfinite(q).all() or np.linalg.norm(q) < 1e-9:
        raise ValueError(f"{path}: rotation is not a quaternion: {q.tolist()}")
    return position, Rotation.from_quat(q / np.linalg.norm(q))


def compose(transforms: Iterable[Transform], root: str) -> dict[str, np.ndarray]:
    """Each frame reachable from `root` through `transforms`: its 4x4 pose in `root`."""
    by_parent: dict[str, list[Transform]] = {}
    for t in transforms:
        by_parent.setdefault(t.parent, []).append(t)
    poses = {root: np.eye(4)}
    stack = [root]
    while stack:
        frame = stack.pop()
        for t in by_parent.get(frame, []):
            if t.child not in poses:
                poses[t.child] = poses[frame] @ t.matrix()
                stack.append(t.child)
    return poses
