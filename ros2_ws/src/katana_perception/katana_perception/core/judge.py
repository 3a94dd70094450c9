"""The outcome judge (paper section 2.3): compare the scene before and after a placement.

The real robot "obtains the outcome label by comparing two images of the configurations
before and after the placement". Stable (+1) needs all of:
- the placed block is seen, with its top face in full view (nothing fell onto it),
- its centre, taken at the height it should have (state + 1 blocks), is within a tolerance
  of the placement point,
- every block of the supporting stack is where it was: none is in full view again (the
  placed block covers the top one), none seen partly has pixels outside where it was, and
  the image pixels the stack showed before still show the stack or the placed block.
Anything else is fell (-1), with the first failed check as the reason.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from katana_description.models import stands_upright

from .calibration import Calibration
from .memory import Block
from .segmentation import Detection, Segmenter, box_corners

STABLE, FELL = 1, -1


@dataclass
class JudgeParams:
    position_tolerance: float = 0.015  # m, placed block centre vs placement point
    # m: a partly seen support block's pixels may lie this far outside where it was
    support_tolerance: float = 0.006
    changed_fraction: float = 0.15  # share of the stack's former pixels allowed to change


@dataclass
class Placement:
    """What was attempted: the fovea instance's state, placement point and stack."""

    state: int
    x: float
    y: float
    support_ids: tuple[str, ...] = ()


@dataclass
class Snapshot:
    labels: np.ndarray
    detections: dict[str, Detection]
    blocks: dict[str, Block]


@dataclass
class Verdict:
    label: int
    reason: str


class Judge:
    def __init__(self, segmenter: Segmenter, calibration: Calibration,
                 params: JudgeParams | None = None) -> None:
        self.segmenter = segmenter
        self.calibration = calibration
        self.params = params or JudgeParams()

    def snapshot(self, rgb: np.ndarray, blocks: Sequence[Block] = (),
                 levels: Mapping[str, int] | None = None) -> Snapshot:
        labels = self.segmenter.label_image(rgb)
        lv = {b.id: b.level for b in blocks}
        lv.update(levels or {})
        dets = self.segmenter.segment_labels(labels, self.calibration, lv)
        return Snapshot(labels, {d.color: d for d in dets}, {b.id: b for b in blocks})

    def judge(self, before: Snapshot, after_rgb: np.ndarray, placed_id: str,
              placement: Placement) -> Verdict:
        p = self.params
        c = self.calibration
        h = self.segmenter.block_size[2]
        s = int(placement.state)
        levels = {b.id: b.level for b in before.blocks.values()}
        levels[placed_id] = s + 1
        after = self.snapshot(after_rgb, (), levels)
        det = after.detections.get(placed_id)
        if det is None:
            return Verdict(FELL, f"{placed_id} is not visible after the placement")
        x, y = (float(a) for a in c.pixel_to_world(det.u, det.v, (s + 1) * h))
        miss = math.hypot(x - placement.x, y - placement.y)
        if miss > p.position_tolerance:
            return Verdict(FELL, f"{placed_id} is {miss * 1000:.0f} mm from the placement "
                           f"point (tolerance {p.position_tolerance * 1000:.0f} mm)")
        if not det.complete:
            return Verdict(FELL, f"{placed_id} is partly covered: something fell onto it")
        if not stands_upright(det.size):
            return Verdict(FELL, f"{placed_id} lies on its side")
        for sid in placement.support_ids:
            sd = after.detections.get(sid)
            mem = before.blocks.get(sid)
            if sd is None:
                continue  # hidden under the blocks above it, as it should be
            if sd.complete:
                return Verdict(FELL, f"support block {sid} is in full view: nothing is on it")
            if mem is not None:
                # Partly covered, its centre estimate is poor; its pixels are not: they must
                # still lie where the block was (its silhouette, grown by the tolerance).
                out = outside_fraction(sd, mem, c, after.labels.shape, p.support_tolerance)
                if out > 0.1:
                    return Verdict(FELL, f"support block {sid} moved: {out:.0%} of its pixels "
                                   "lie outside where it was")
        if placement.support_ids:
            names = self.segmenter.names
            support_vals = [names.index(i) + 1 for i in placement.support_ids if i in names]
            region = np.isin(before.labels, support_vals)
            n = int(region.sum())
            if n:
                now = after.labels[region]
                was = before.labels[region]
                placed_val = names.index(placed_id) + 1 if placed_id in names else -1
                changed = float(((now != was) & (now != placed_val)).sum()) / n
                if changed > p.changed_fraction:
                    return Verdict(FELL, f"{changed:.0%} of the stack's pixels changed")
        return Verdict(STABLE, f"{placed_id} rests at level {s + 1}, "
                       f"{miss * 1000:.0f} mm from the placement point")


def silhouette(calib: Calibration, b: Block, shape: tuple[int, int], grow_m: float) -> np.ndarray:
    """Image region of a block (top and side faces: the hull of its 8 projected corners),
    grown by grow_m in the table plane."""
    grown = (b.size[0] + 2 * grow_m, b.size[1] + 2 * grow_m, b.size[2])
    corners = box_corners(b.x, b.y, b.top_z - b.size[2], b.yaw, grown)
    hull = cv2.convexHull(calib.project(corners).astype(np.float32))
    mask = np.zeros(shape, dtype=np.uint8)
    cv2.fillPoly(mask, [np.rint(hull).astype(np.int32)], 1)
    return mask.astype(bool)


def outside_fraction(det: Detection, b: Block, calib: Calibration, shape: tuple[int, int],
                     grow_m: float) -> float:
    """Share of a detection's pixels outside the block's remembered silhouette."""
    region = silhouette(calib, b, shape, grow_m)
    x, y, w, h = det.bbox
    inside = region[y:y + h, x:x + w][det.mask]
    return float(1.0 - inside.mean()) if inside.size else 0.0
