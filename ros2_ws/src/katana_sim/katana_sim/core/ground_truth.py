"""The simulated world's ground truth: each block's pose, stack level and visibility, from the
block poses alone (no physics stepping). Levels come from geometry: a block resting on the
table is level 1; one whose bottom face touches another block's top face, overlapping it, is
one level higher."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pybullet as p
from katana_description import models as m

from katana_sim.core.camera import CameraModel

Pose = tuple[Sequence[float], Sequence[float]]  # position (x, y, z), quaternion (x, y, z, w)


@dataclass
class BlockState:
    """True state of one block (frame `world`)."""

    id: str
    color: str
    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]  # x, y, z, w
    yaw: float  # about +z, in (-pi/2, pi/2]
    size: tuple[float, float, float]
    level: int  # 1 on the table, 2 on one block, ...
    on_top: bool  # nothing rests on it
    visible: bool  # its top face is in the image and not covered by another block (the arm is
    # not considered: park it out of view before an image is taken)
    tilted: bool  # not lying flat (fell over, leaning)
    pixel_u: float
    pixel_v: float
    pixel_angle: float  # direction of the block's x axis in the image, rad (mod pi)
    support: str = ""  # id of the block it rests on; "" for the table


def yaw_of(quat) -> float:
    """Yaw of the block's x axis in (-pi/2, pi/2] (a cuboid is symmetric under half turns)."""
    rot = np.array(p.getMatrixFromQuaternion(quat)).reshape(3, 3)
    yaw = math.atan2(rot[1, 0], rot[0, 0])
    while yaw <= -math.pi / 2:
        yaw += math.pi
    while yaw > math.pi / 2:
        yaw -= math.pi
    return yaw


def block_states(poses: Mapping[str, Pose], block_size: Sequence[float],
                 camera: CameraModel) -> list[BlockState]:
    """True poses, stack levels and visibility of every block, in the order of `poses`."""
    order = list(poses)
    sx, sy, h = block_size
    raw = []
    for bid, (pos, quat) in poses.items():
        rot = np.array(p.getMatrixFromQuaternion(quat)).reshape(3, 3)
        raw.append((bid, np.array(pos), quat, rot))
    raw.sort(key=lambda r: r[1][2])
    footprint = 0.5 * min(sx, sy) + 0.5 * max(sx, sy)  # centre distance allowing overlap
    level: dict[str, int] = {}
    support: dict[str, str] = {}
    covered: set[str] = set()
    for i, (bid, pos, _, _rot) in enumerate(raw):
        best = ""
        for other, opos, _, _ in raw[:i]:
            dz = pos[2] - opos[2]
            if abs(dz - h) < 0.4 * h and np.hypot(*(pos[:2] - opos[:2])) < footprint:
                if not best or level[other] > level[best]:
                    best = other
        if best:
            level[bid] = level[best] + 1
            support[bid] = best
            covered.add(best)
        else:
            level[bid] = max(1, int(round((pos[2] - 0.5 * h) / h)) + 1)
    # A block is also hidden when any block lies above it and overlaps it in xy.
    for bid, pos, _, _ in raw:
        for other, opos, _, _ in raw:
            if other != bid and opos[2] > pos[2] + 0.5 * h and np.hypot(
                *(pos[:2] - opos[:2])
            ) < footprint:
                covered.add(bid)
    result = []
    for bid, pos, quat, rot in sorted(raw, key=lambda r: order.index(r[0])):
        up = rot[:, 2] if abs(rot[2, 2]) > 0.5 else np.array([0.0, 0.0, 1.0])
        top = pos + np.sign(up[2]) * up * (h / 2)
        ends = camera.project(np.array([top, top + rot[:, 0] * (sx / 2)]))
        uv = ends[0]
        in_view = bool(camera.in_view(top[None, :])[0])
        angle = math.atan2(ends[1][1] - uv[1], ends[1][0] - uv[0])
        angle = (angle + math.pi / 2) % math.pi - math.pi / 2
        result.append(
            BlockState(
                id=bid, color=bid, position=tuple(pos.tolist()), quaternion=tuple(quat),
                yaw=yaw_of(quat), size=tuple(block_size), level=level[bid],
                on_top=bid not in covered, visible=in_view and bid not in covered,
                tilted=not m.lies_flat(*quat),
                pixel_u=float(uv[0]) if in_view else math.nan,
                pixel_v=float(uv[1]) if in_view else math.nan,
                pixel_angle=angle if in_view else math.nan,
                support=support.get(bid, ""),
            )
        )
    return result
