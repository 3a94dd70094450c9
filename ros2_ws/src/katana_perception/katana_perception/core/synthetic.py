"""A small top-down renderer of coloured cuboids, for tests and benchmarks.

Pinhole projection through a Calibration, back-face culling, painter's order by depth,
Lambertian shading, anti-aliased cv2.fillPoly, optional pixel noise. It also renders an id
buffer (which block face covers each pixel) for ground truth: what is visible, how much of
each top face. It exists because tests need thousands of exactly-known scenes in
milliseconds; the PyBullet sim (katana_sim) is the realistic check.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from katana_description.models import BLOCK_SIZE
from scipy.spatial.transform import Rotation

from .calibration import Calibration
from .colors import NOMINAL_RGB

TOP_FACE = 4  # index of the +z face in FACES
# Faces as (axis, sign); corners are listed counter-clockwise seen from outside.
FACES = ((0, 1), (0, -1), (1, 1), (1, -1), (2, 1), (2, -1))
_SHIFT = 4


@dataclass
class SceneBlock:
    name: str
    x: float
    y: float
    z: float  # centre height, m
    yaw: float = 0.0
    roll: float = 0.0
    pitch: float = 0.0
    size: tuple[float, float, float] = BLOCK_SIZE
    rgb: tuple[float, float, float] | None = None
    level: int = 1  # ground truth, for tests; not used to draw

    def rotation(self) -> np.ndarray:
        return Rotation.from_euler("xyz", [self.roll, self.pitch, self.yaw]).as_matrix()

    def corners(self, face: int) -> np.ndarray:
        """World corners (4x3) of one face."""
        axis, sign = FACES[face]
        others = [a for a in range(3) if a != axis]
        half = np.asarray(self.size) / 2.0
        quad = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], dtype=float)
        local = np.zeros((4, 3))
        local[:, axis] = sign * half[axis]
        local[:, others[0]] = quad[:, 0] * half[others[0]]
        local[:, others[1]] = quad[:, 1] * half[others[1]]
        return local @ self.rotation().T + [self.x, self.y, self.z]

    def normal(self, face: int) -> np.ndarray:
        axis, sign = FACES[face]
        return self.rotation()[:, axis] * sign


@dataclass
class Renderer:
    calibration: Calibration
    table_rgb: tuple[float, float, float] = (0.78, 0.78, 0.78)
    light: Sequence[float] = (0.3, 0.2, 1.0)  # direction towards the light, world
    ambient: float = 0.45
    noise_sigma: float = 2.0  # grey levels
    vignette: float = 0.12  # relative darkening at the image corners
    _cache: dict = field(default_factory=dict, repr=False)

    def render(
        self, blocks: Sequence[SceneBlock], seed: int | None = 0
    ) -> tuple[np.ndarray, np.ndarray]:
        """RGB uint8 image and int32 id buffer (-1 table, 8 * block index + face)."""
        c = self.calibration
        h, w = c.height, c.width
        key = (h, w, self.table_rgb, self.vignette)
        if key not in self._cache:
            yy, xx = np.mgrid[0:h, 0:w]
            r2 = ((xx - w / 2) / (w / 2)) ** 2 + ((yy - h / 2) / (h / 2)) ** 2
            shade = 1.0 - self.vignette * r2 / 2.0
            base = (np.asarray(self.table_rgb)[None, None, :] * shade[:, :, None]) * 255.0
            self._cache[key] = base.astype(np.float32)
        img = self._cache[key].copy()
        ids = np.full((h, w), -1, dtype=np.int32)
        light = np.asarray(self.light, dtype=float)
        light = light / np.linalg.norm(light)
        faces = []
        for bi, b in enumerate(blocks):
            for f in range(6):
                corners = b.corners(f)
                n = b.normal(f)
                centre = corners.mean(axis=0)
                if (centre - c.centre) @ n >= 0:  # facing away from the camera
                    continue
                depth = float(np.linalg.norm(centre - c.centre))
                faces.append((depth, bi, f, corners, n))
        faces.sort(key=lambda t: -t[0])
        for _, bi, f, corners, n in faces:
            b = blocks[bi]
            rgb = np.asarray(b.rgb if b.rgb is not None else NOMINAL_RGB[b.name])
            k = self.ambient + (1.0 - self.ambient) * max(0.0, float(n @ light))
            colour = tuple(float(v) for v in np.clip(rgb * k * 255.0, 0, 255))
            uv = c.project(corners)
            poly = np.rint(uv * (1 << _SHIFT)).astype(np.int32).reshape(1, -1, 2)
            cv2.fillPoly(img, poly, colour, lineType=cv2.LINE_AA, shift=_SHIFT)
            cv2.fillPoly(ids, poly, 8 * bi + f, lineType=cv2.LINE_8, shift=_SHIFT)
        if self.noise_sigma > 0:
            rng = np.random.default_rng(seed)
            img += rng.normal(0.0, self.noise_sigma, img.shape).astype(np.float32)
        return np.clip(img, 0, 255).astype(np.uint8), ids

    def top_face_area(self, block: SceneBlock) -> int:
        """Pixels the block's top face would cover with nothing in front of it."""
        c = self.calibration
        ids = np.full((c.height, c.width), -1, dtype=np.int32)
        uv = c.project(block.corners(TOP_FACE))
        poly = np.rint(uv * (1 << _SHIFT)).astype(np.int32).reshape(1, -1, 2)
        cv2.fillPoly(ids, poly, 1, lineType=cv2.LINE_8, shift=_SHIFT)
        return int((ids == 1).sum())

    def top_centre_pixel(self, block: SceneBlock) -> np.ndarray:
        top = block.corners(TOP_FACE).mean(axis=0)
        return self.calibration.project(top[None, :])[0]


def stack_block(name: str, x: float, y: float, level: int, yaw: float = 0.0,
                size: tuple[float, float, float] = BLOCK_SIZE) -> SceneBlock:
    """A block resting flat at `level` (1 = on the table)."""
    return SceneBlock(name, x, y, (level - 0.5) * size[2], yaw=yaw, size=size, level=level)


def random_scene(
    rng: np.random.Generator,
    names: Sequence[str],
    max_height: int = 3,
    max_offset: float = 0.012,
    area_x: tuple[float, float] = (0.14, 0.30),
    area_y: tuple[float, float] = (-0.16, 0.16),
    radius: tuple[float, float] = (0.14, 0.29),
    min_gap: float = 0.012,
) -> list[SceneBlock]:
    """Blocks in random stacks (heights 1..max_height) scattered without overlap.

    A block on a stack is offset by up to max_offset (each axis) from the one below and
    turned by up to 0.3 rad: stable-looking, partly covering the block below.
    """
    names = list(names)
    rng.shuffle(names)
    stacks: list[list[str]] = []
    i = 0
    while i < len(names):
        hgt = int(rng.integers(1, max_height + 1))
        stacks.append(names[i:i + hgt])
        i += hgt
    size = BLOCK_SIZE
    half_diag = 0.5 * math.hypot(size[0], size[1])
    reach = [half_diag + (len(st) - 1) * max_offset * math.sqrt(2.0) for st in stacks]
    for _ in range(500):
        bases: list[tuple[float, float]] = []
        for k in range(len(stacks)):
            for _try in range(300):
                x, y = rng.uniform(*area_x), rng.uniform(*area_y)
                if not radius[0] + 0.01 <= math.hypot(x, y) <= radius[1] - 0.01:
                    continue
                if any(math.hypot(x - a, y - b) < reach[k] + reach[j] + min_gap
                       for j, (a, b) in enumerate(bases)):
                    continue
                bases.append((x, y))
                break
            else:
                break
        if len(bases) == len(stacks):
            break
    else:
        raise RuntimeError("could not scatter the stacks")
    out = []
    for stack, (x, y) in zip(stacks, bases, strict=True):
        yaw = float(rng.uniform(-math.pi / 4, math.pi / 4))
        for level, name in enumerate(stack, start=1):
            if level > 1:
                x += float(rng.uniform(-max_offset, max_offset))
                y += float(rng.uniform(-max_offset, max_offset))
                yaw += float(rng.uniform(-0.3, 0.3))
            out.append(stack_block(name, x, y, level, yaw))
    return out


def visible_fraction(renderer: Renderer, blocks: Sequence[SceneBlock], ids: np.ndarray) -> dict:
    """Share of each block's top face that is in view (ground truth for detection tests)."""
    out = {}
    for bi, b in enumerate(blocks):
        full = renderer.top_face_area(b)
        out[b.name] = float((ids == 8 * bi + TOP_FACE).sum()) / full if full else 0.0
    return out
