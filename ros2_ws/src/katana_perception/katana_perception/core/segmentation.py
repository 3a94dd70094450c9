"""Colour segmentation of the overhead image into blocks (paper section 2.1).

One block per colour-table entry. The image is converted to HSV once; a hue lookup table
labels every saturated, bright-enough pixel with its colour; a 3x3 median removes speckle
and the one-pixel hue fringes anti-aliasing leaves between two colours. Per colour, the
connected components near the largest one form the block (a block on top can split the one
below in two).

The camera sees a block's top face plus the side faces that lean away from the nadir (the
image of the vertical through the camera). Centroids of the whole blob are therefore biased
towards the nadir by up to half a side face (about 4 px here), and a block partly covered by
one on top loses part of its top face. Given the calibration and the block's level (from the
memory; 1 when unknown), the top face, a square of known pixel size, is placed against the
blob's outer edge along each of its two axes, or against its inner edge plus the side face
when the outer edge is covered by another block.

A block that fell can lie on its side: its top face is then a rectangle and it stands taller
than a level. For a fully visible block the silhouettes of the three resting boxes (upright,
or on either side) are projected through the calibration, each moved until its centroid
meets the blob's, and the one overlapping the blob best (by a margin, else upright) gives
the block's resting size. The image outline alone cannot tell: side faces widen a square top
by up to a third of its edge here, as much as a side lying block is narrower.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from katana_description.models import BLOCK_SIZE

from .calibration import Calibration
from .colors import DEFAULT_COLOR_TABLE, ColorRange


def wrap_quarter(angle: float) -> float:
    """Angle modulo pi/2 into (-pi/4, pi/4]: a square looks the same turned by 90 degrees."""
    a = (angle + np.pi / 4) % (np.pi / 2) - np.pi / 4
    return float(np.pi / 4 if np.isclose(a, -np.pi / 4) else a)


@dataclass
class Detection:
    """One visible block in one image."""

    color: str
    u: float  # estimated centre of the top face, px
    v: float
    angle: float  # image angle of one edge of the top face, rad, in (-pi/4, pi/4]
    area: int  # pixels of the blob
    bbox: tuple[int, int, int, int]  # x, y, w, h of the blob in the image
    mask: np.ndarray  # bool, bbox-sized: the blob's pixels
    top_px: float  # expected edge length of the top face in the image, px
    level: int  # level assumed for the estimate (1 = on the table)
    complete: bool  # top face not covered by another block: nothing rests on it
    # resting extents, m: along the image direction `angle`, across it, and vertical;
    # z above the smallest edge means the block lies on its side
    size: tuple[float, float, float] = BLOCK_SIZE

    def pixels(self) -> np.ndarray:
        """Nx2 (u, v) image coordinates of the blob's pixels."""
        ys, xs = np.nonzero(self.mask)
        return np.column_stack([xs + self.bbox[0], ys + self.bbox[1]]).astype(np.float64)

    def full_mask(self, shape: tuple[int, int]) -> np.ndarray:
        out = np.zeros(shape, dtype=bool)
        x, y, w, h = self.bbox
        out[y:y + h, x:x + w] = self.mask
        return out


class Segmenter:
    """Colour table -> per-block detections. Apart from its settings it keeps only the
    resting sizes of the last image's blobs: while the arm moves, the blocks it does not
    carry give the same blobs frame after frame, and their silhouette fits are reused."""

    def __init__(
        self,
        table: Sequence[ColorRange] = DEFAULT_COLOR_TABLE,
        s_min: int = 80,
        v_min: int = 40,
        min_area_px: int = 120,
        min_inscribed_px: float = 6.0,
        block_size: tuple[float, float, float] = BLOCK_SIZE,
        occlusion_threshold: float = 0.04,
        median: bool = True,
        side_margin: float = 0.04,
    ) -> None:
        if not table:
            raise ValueError("the colour table is empty")
        if not (0 <= s_min <= 255 and 0 <= v_min <= 255):
            raise ValueError(f"s_min and v_min must be in 0..255, got {s_min}, {v_min}")
        self.table = tuple(table)
        self.names = [c.name for c in self.table]
        self.s_min, self.v_min = int(s_min), int(v_min)
        self.min_area_px = int(min_area_px)
        self.min_inscribed_px = float(min_inscribed_px)
        self.block_size = tuple(float(s) for s in block_size)
        self.occlusion_threshold = float(occlusion_threshold)
        self.median = median
        # IoU by which a side-lying silhouette must beat the upright one. On 165 sim renders
        # over the reach, upright blocks scored >= -0.003 (upright minus side), blocks on
        # their side <= -0.08.
        self.side_margin = float(side_margin)
        self._resting: dict[tuple, tuple] = {}  # blob -> (calibration, size, centre), last image
        self._resting_now: dict[tuple, tuple] = {}
        lut = np.zeros(256, dtype=np.uint8)
        for i, c in enumerate(self.table):
            for lo, hi in c.hues:
                lut[lo:hi + 1] = i + 1
        self._lut = lut

    # ------------------------------------------------------------------ labels
    def label_image(self, rgb: np.ndarray) -> np.ndarray:
        """uint8 image: 0 for background, i + 1 for a pixel of colour table entry i."""
        check_rgb(rgb)
        hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
        chroma = cv2.inRange(hsv, (0, self.s_min, self.v_min), (255, 255, 255))
        hue = hsv[:, :, 0]
        labels = cv2.bitwise_and(cv2.LUT(hue, self._lut), chroma)
        if self.median:
            labels = cv2.medianBlur(labels, 3)
        return labels

    # ------------------------------------------------------------------ blocks
    def segment(self, rgb: np.ndarray, calibration: Calibration | None = None,
                levels: Mapping[str, int] | None = None) -> list[Detection]:
        """Every block visible in `rgb`, in colour-table order."""
        return self.segment_labels(self.label_image(rgb), calibration, levels)

    def segment_labels(
        self,
        labels: np.ndarray,
        calibration: Calibration | None = None,
        levels: Mapping[str, int] | None = None,
    ) -> list[Detection]:
        out: list[Detection] = []
        levels = levels or {}
        self._resting, self._resting_now = self._resting_now, {}
        # Find each colour's region on a 4x subsampled grid, then label components only in
        # that crop: a full-frame connected-components pass per colour costs ~1 ms each.
        step = 4
        small = labels[::step, ::step]
        present = np.bincount(small.ravel(), minlength=len(self.table) + 1)
        h, w = labels.shape
        for i, name in enumerate(self.names):
            if present[i + 1] * step * step < self.min_area_px // 2:
                continue
            ys, xs = np.nonzero(small == i + 1)
            pad = 2 * step
            x0 = max(0, int(xs.min()) * step - pad)
            y0 = max(0, int(ys.min()) * step - pad)
            x1 = min(w, int(xs.max()) * step + pad + 1)
            y1 = min(h, int(ys.max()) * step + pad + 1)
            blob = self._blob(labels[y0:y1, x0:x1], i + 1)
            if blob is None:
                continue
            (bx, by, bw, bh), sub, area = blob
            blob = (bx + x0, by + y0, bw, bh), sub, area
            det = self._describe(name, i + 1, blob, labels, calibration,
                                 max(1, int(levels.get(name, 1))))
            if det is not None:
                out.append(det)
        return out

    def _blob(self, labels: np.ndarray, value: int):
        """The block's pixels: the largest component plus nearby pieces of the same colour."""
        mask = cv2.compare(labels, value, cv2.CMP_EQ)
        n, comp, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        if n <= 1:
            return None
        areas = stats[1:, cv2.CC_STAT_AREA]
        big = int(np.argmax(areas)) + 1
        if areas[big - 1] < max(20, self.min_area_px // 4):
            return None
        bx, by, bw, bh = stats[big, :4]
        reach = 1.2 * max(bw, bh)
        keep = [big]
        for j in range(1, n):
            if j == big or stats[j, cv2.CC_STAT_AREA] < 20:
                continue
            x, y, w, h = stats[j, :4]
            gap_x = max(0, max(x - (bx + bw), bx - (x + w)))
            gap_y = max(0, max(y - (by + bh), by - (y + h)))
            if max(gap_x, gap_y) <= reach:
                keep.append(j)
        x0 = min(stats[j, 0] for j in keep)
        y0 = min(stats[j, 1] for j in keep)
        x1 = max(stats[j, 0] + stats[j, 2] for j in keep)
        y1 = max(stats[j, 1] + stats[j, 3] for j in keep)
        crop = comp[y0:y1, x0:x1]
        sub = crop == keep[0] if len(keep) == 1 else np.isin(crop, keep)
        area = int(sum(stats[j, cv2.CC_STAT_AREA] for j in keep))
        if area < self.min_area_px:
            return None
        return (int(x0), int(y0), int(x1 - x0), int(y1 - y0)), sub, area

    def _describe(self, name, value, blob, labels, calib, level) -> Detection | None:
        (x0, y0, w, h), sub, area = blob
        padded = np.pad(sub.astype(np.uint8), 1)
        if cv2.distanceTransform(padded, cv2.DIST_L2, 3).max() < self.min_inscribed_px:
            return None  # only a sliver (side faces of a covered block, colour fringes)
        ys, xs = np.nonzero(sub)
        pts = np.column_stack([xs + x0, ys + y0]).astype(np.float32)
        _, _, deg = cv2.minAreaRect(pts)
        theta = wrap_quarter(np.deg2rad(deg))
        centre, axes, top = self._fit(pts, theta, labels, value, calib, level)
        occ = self._occlusion(labels, value, centre, axes, top)
        complete = occ < self.occlusion_threshold
        size = self.block_size
        if calib is not None and complete:
            key = (name, level, x0, y0, w, h, area, theta, id(calib), sub.tobytes())
            found = self._resting.get(key)
            if found is None:  # (the calibration is kept with it: its id stays its own)
                found = (calib, *self._resting_size(sub, (x0, y0), theta, calib, level))
            self._resting_now[key] = found
            _, size, side_centre = found
            if side_centre is not None:
                centre = side_centre
        return Detection(
            color=name, u=float(centre[0]), v=float(centre[1]), angle=theta, area=area,
            bbox=(x0, y0, w, h), mask=sub, top_px=float(top), level=level,
            complete=complete, size=size,
        )

    def _resting_size(self, sub, origin, theta, calib, level):
        """(size, None) for an upright block; (size, top-face centre px) for one on its side."""
        sx, sy, sz = self.block_size
        z_bottom = (level - 1) * sz
        ys, xs = np.nonzero(sub)
        blob_uv = np.array([xs.mean() + origin[0], ys.mean() + origin[1]])
        fits = [_fit_box(calib, sub, origin, blob_uv, theta, size, z_bottom)
                for size in ((sx, sy, sz), (sx, sz, sy), (sz, sy, sx))]
        best = max((1, 2), key=lambda k: fits[k][0])
        if fits[best][0] <= fits[0][0] + self.side_margin:
            return self.block_size, None
        size = ((sx, sz, sy), (sz, sy, sx))[best - 1]
        return size, fits[best][1]

    def _fit(self, pts, theta, labels, value, calib, level):
        """Top-face centre for edge direction theta: centre, axes, top edge length (px)."""
        axes = np.array([[np.cos(theta), np.sin(theta)], [-np.sin(theta), np.cos(theta)]])
        proj = pts.astype(np.float64) @ axes.T  # coordinates along the two edge axes
        lo = proj.min(axis=0) - 0.5  # pixel centres -> pixel edges
        hi = proj.max(axis=0) + 0.5
        if calib is None:
            return ((lo + hi) / 2.0) @ axes, axes, float(max(hi - lo))
        side_m = (self.block_size[0] + self.block_size[1]) / 2.0
        h_m = self.block_size[2]
        z_top, z_bot = level * h_m, (level - 1) * h_m
        mid = (lo + hi) / 2.0 @ axes
        top = side_m * calib.pixels_per_metre(mid[0], mid[1], z_top)
        q = (mid - calib.nadir()) @ axes.T
        t = np.empty(2)
        for k in range(2):
            o = 1 - k
            s = 1.0 if q[k] >= 0 else -1.0
            outer, inner = (hi[k], lo[k]) if s > 0 else (lo[k], hi[k])
            span = (lo[o], hi[o])
            if self._free(labels, value, axes, k, outer, s, span):
                t[k] = outer - s * top / 2.0
                continue
            strip = 0.0
            if abs(q[k]) > top / 2.0:  # the inner side face is in view
                p_in = inner * axes[k] + (lo[o] + hi[o]) / 2.0 * axes[o]
                wx, wy = calib.pixel_to_world(p_in[0], p_in[1], z_bot)
                pu, pv = calib.world_to_pixel(wx, wy, z_top)
                strip = abs((np.array([float(pu), float(pv)]) - p_in) @ axes[k])
            if self._free(labels, value, axes, k, inner, -s, span):
                t[k] = inner + s * (strip + top / 2.0)
            else:
                t[k] = (lo[k] + hi[k]) / 2.0 + s * strip / 2.0
        return t @ axes, axes, float(top)

    @staticmethod
    def _sample(labels: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """Labels at points; 255 marks points outside the image (or not finite, or beyond
        any int: a degenerate calibration sends the top face nowhere)."""
        h, w = labels.shape
        finite = (np.abs(pts) < 1e9).all(axis=1)  # False for NaN too
        iu = np.full(len(pts), -1)
        iv = np.full(len(pts), -1)
        iu[finite] = np.rint(pts[finite, 0]).astype(int)
        iv[finite] = np.rint(pts[finite, 1]).astype(int)
        inside = (iu >= 0) & (iu < w) & (iv >= 0) & (iv < h)
        out = np.full(len(pts), 255, dtype=np.int32)
        out[inside] = labels[iv[inside], iu[inside]]
        return out

    def _free(self, labels, value, axes, k, end, direction, span) -> bool:
        """True when just beyond this edge lies background: the edge is the block's own."""
        o = 1 - k
        ts = np.linspace(span[0] + 2.0, span[1] - 2.0, 12)
        pts = []
        for d in (1.5, 3.0):
            along = end + direction * d
            pts.append(np.outer(np.full_like(ts, along), axes[k]) + np.outer(ts, axes[o]))
        got = self._sample(labels, np.vstack(pts))
        foreign = (got != 0) & (got != value)
        return float(foreign.mean()) < 0.2

    def _occlusion(self, labels, value, centre, axes, top) -> float:
        g = (np.arange(10) + 0.5) / 10.0 - 0.5
        a, b = np.meshgrid(g, g)
        half = max(top - 4.0, 2.0)
        pts = centre + (a.ravel() * half)[:, None] * axes[0] + (b.ravel() * half)[:, None] * axes[1]
        got = self._sample(labels, pts)
        return float(((got != 0) & (got != value)).mean())


def box_corners(x: float, y: float, z_bottom: float, yaw: float, size) -> np.ndarray:
    """8x3 world corners of a box resting at (x, y) on the plane z_bottom, turned by yaw."""
    c, s = math.cos(yaw), math.sin(yaw)
    half = np.array([[i, j] for i in (-0.5, 0.5) for j in (-0.5, 0.5)]) * size[:2]
    xy = np.column_stack([x + c * half[:, 0] - s * half[:, 1], y + s * half[:, 0] + c * half[:, 1]])
    return np.vstack([np.column_stack([xy, np.full(4, z_bottom + dz)]) for dz in (0.0, size[2])])


def _fit_box(calib: Calibration, sub: np.ndarray, origin, blob_uv: np.ndarray, theta: float,
             size, z_bottom: float, moves: int = 2) -> tuple[float, np.ndarray]:
    """IoU of a box's silhouette with a blob, the box moved until the centroids meet, and
    the image point of its top-face centre. A box's silhouette is the convex hull of its
    projected corners."""
    h, w = sub.shape
    pad = 16
    z_mid = z_bottom + size[2] / 2.0
    yaw = calib.image_angle_to_yaw(blob_uv[0], blob_uv[1], theta, z_mid)
    x, y = (float(a) for a in calib.pixel_to_world(blob_uv[0], blob_uv[1], z_mid))
    offset = np.array([origin[0] - pad, origin[1] - pad], dtype=np.float64)
    box = np.zeros((h + 2 * pad, w + 2 * pad), np.uint8)

    def draw() -> dict:  # the silhouette's image moments
        uv = calib.project(box_corners(x, y, z_bottom, yaw, size))
        box[:] = 0
        cv2.fillConvexPoly(box, cv2.convexHull(np.rint((uv - offset) * 16).astype(np.int32)),
                           1, lineType=cv2.LINE_8, shift=4)
        return cv2.moments(box, binaryImage=True)

    for _ in range(moves):
        m = draw()
        if m["m00"] == 0:
            return 0.0, blob_uv
        got = np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]]) + offset
        wx, wy = calib.pixel_to_world([blob_uv[0], got[0]], [blob_uv[1], got[1]], z_mid)
        x, y = x + float(wx[0] - wx[1]), y + float(wy[0] - wy[1])
    draw()
    blob = np.zeros(box.shape, dtype=bool)
    blob[pad:pad + h, pad:pad + w] = sub
    filled = box.astype(bool)
    iou = float((blob & filled).sum() / max(1, (blob | filled).sum()))
    top = calib.project(np.array([[x, y, z_bottom + size[2]]]))[0]
    return iou, top


def check_rgb(rgb: np.ndarray) -> None:
    """Reject what is not an HxWx3 uint8 image, with the reason."""
    if not isinstance(rgb, np.ndarray):
        raise ValueError(f"image must be a numpy array, got {type(rgb).__name__}")
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"image must be HxWx3 (RGB), got shape {rgb.shape}")
    if rgb.dtype != np.uint8:
        raise ValueError(f"image must be uint8, got {rgb.dtype}")
    if rgb.shape[0] < 8 or rgb.shape[1] < 8:
        raise ValueError(f"image too small: {rgb.shape[1]}x{rgb.shape[0]}")
