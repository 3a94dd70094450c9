"""Block memory (paper section 2.1): what the overhead camera cannot see.

The camera sees top faces only, so heights and occluded blocks live here. Stacks are a
support graph (each block rests on the table or on one block), so levels and on-top flags
are derived, never stored, and the setting is always consistent: no two blocks on one
block, no cycles, level = 1 + level of the support.

Updates:
- from detections: a block seen where it was remembered keeps its support; a block seen
  elsewhere fell or was moved (it and everything that rested on it go to the table, unless
  it now covers a block, in which case it rests on that stack); a block not seen but under
  a block stays remembered; a block neither seen nor covered is missing (kept in place, in
  case the arm hides it, and reported as not visible) until it reappears;
- from an experiment's outcome: stable puts the placed block on the stack it was placed
  on; fell puts it on the table (the next detections sort out the rest of the stack).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from katana_description.models import BLOCK_SIZE, stands_upright

from .calibration import Calibration
from .segmentation import wrap_quarter


@dataclass
class Block:
    """One block as remembered. Pose is the block's centre in the world frame."""

    id: str
    color: str
    x: float
    y: float
    yaw: float
    support: str | None = None  # id of the block it rests on; None = the table
    level: int = 1  # derived from support (kept in sync by BlockMemory)
    on_top: bool = True  # derived: nothing rests on it
    visible: bool = False  # seen in the last image
    pixel_u: float = math.nan
    pixel_v: float = math.nan
    pixel_angle: float = math.nan
    size: tuple[float, float, float] = BLOCK_SIZE
    missing: int = 0  # consecutive updates in which it was neither seen nor covered
    rest_frame: int = -1  # the last update in which it was seen where it was remembered
    # its resting extents come from a clean view since it last moved: a block that came to rest
    # partly covered (by a stack's parallax, say) may lie on its side without anyone knowing
    pose_known: bool = False

    @property
    def z(self) -> float:
        return self.top_z - self.size[2] / 2.0

    @property
    def top_z(self) -> float:
        return top_height(self.level, self.size)

    @property
    def upright(self) -> bool:
        return stands_upright(self.size)


def top_height(level: int, size: Sequence[float]) -> float:
    """Height of a block's top face at `level`, resting on upright blocks of its kind (as tall
    as its shortest edge): a block on its side stands taller than a level."""
    return (level - 1) * min(size) + size[2]


@dataclass
class Seen:
    """A block in the current image (what perception/detections carries)."""

    id: str
    color: str
    u: float
    v: float
    angle: float  # image angle of a top-face edge, rad
    complete: bool  # top face fully visible: nothing rests on it
    # resting size when measured (None: nominal): x along the yaw the angle gives, z vertical
    size: tuple[float, float, float] | None = None


def footprint_overlap(a: Block, b: Block) -> float:
    """Shared area of two blocks' xy footprints, as a fraction of the smaller one."""
    ra = ((a.x * 1000, a.y * 1000), (a.size[0] * 1000, a.size[1] * 1000), math.degrees(a.yaw))
    rb = ((b.x * 1000, b.y * 1000), (b.size[0] * 1000, b.size[1] * 1000), math.degrees(b.yaw))
    kind, pts = cv2.rotatedRectangleIntersection(ra, rb)
    if kind == cv2.INTERSECT_NONE or pts is None or len(pts) < 3:
        return 0.0
    area = cv2.contourArea(cv2.convexHull(pts.reshape(-1, 2).astype(np.float32)))
    smaller = min(a.size[0] * a.size[1], b.size[0] * b.size[1]) * 1e6
    return float(area / smaller)


@dataclass
class MemoryParams:
    position_tolerance: float = 0.015  # m: a seen block farther than this from memory moved
    occluded_tolerance: float = 0.025  # m: the same for a partly covered block
    cover_fraction: float = 0.25  # footprint overlap that makes one block rest on another
    forget_after: int = 0  # drop a block missing this many updates in a row; 0 = never


@dataclass
class BlockMemory:
    calibration: Calibration
    params: MemoryParams = field(default_factory=MemoryParams)
    block_size: tuple[float, float, float] = BLOCK_SIZE
    blocks: dict[str, Block] = field(default_factory=dict)
    frame: int = 0  # updates folded in so far

    # ------------------------------------------------------------------ structure
    def _refresh(self) -> None:
        """Recompute levels and on-top flags from the support graph, repairing it if needed."""
        carried: dict[str, str] = {}
        for b in self.blocks.values():
            if b.support is not None and b.support not in self.blocks:
                b.support = None  # support forgotten: the block is on the table
            if b.support is not None:
                if b.support in carried:  # two blocks on one: the later one falls
                    b.support = None
                else:
                    carried[b.support] = b.id
        for b in self.blocks.values():
            seen: set[str] = set()
            level, s = 1, b.support
            while s is not None:
                if s in seen or s == b.id:  # a cycle: break it here
                    b.support, level = None, 1
                    break
                seen.add(s)
                level += 1
                s = self.blocks[s].support
            b.level = level
        carrying = {b.support for b in self.blocks.values() if b.support is not None}
        for b in self.blocks.values():
            b.on_top = b.id not in carrying

    def stacks(self) -> list[list[Block]]:
        """Every stack, bottom block first, ordered by bottom block id."""
        above = {b.support: b for b in self.blocks.values() if b.support is not None}
        out = []
        for b in sorted(self.blocks.values(), key=lambda b: b.id):
            if b.support is None:
                chain = [b]
                while chain[-1].id in above:
                    chain.append(above[chain[-1].id])
                out.append(chain)
        return out

    def above(self, block_id: str) -> list[str]:
        """Ids resting (directly or not) on a block, lowest first."""
        on = {b.support: b.id for b in self.blocks.values() if b.support is not None}
        out, cur = [], block_id
        while cur in on:
            cur = on[cur]
            out.append(cur)
        return out

    def snapshot(self) -> list[Block]:
        return [replace(b) for b in sorted(self.blocks.values(), key=lambda b: b.id)]

    def levels(self) -> dict[str, int]:
        return {b.id: b.level for b in self.blocks.values()}

    def consistent(self) -> bool:
        """Invariant check: a forest of chains whose levels match the support graph."""
        supports = [b.support for b in self.blocks.values() if b.support is not None]
        if len(supports) != len(set(supports)):
            return False
        for b in self.blocks.values():
            want = 1 if b.support is None else self.blocks[b.support].level + 1
            if b.level != want or b.on_top != (b.id not in supports):
                return False
        return True

    # ------------------------------------------------------------------ geometry
    def _locate(self, s: Seen, level: int, size: Sequence[float]) -> tuple[float, float, float]:
        z_top = top_height(level, size)
        x, y = self.calibration.pixel_to_world(s.u, s.v, z_top)
        yaw = self.calibration.image_angle_to_yaw(s.u, s.v, s.angle, z_top)
        return float(x), float(y), wrap_quarter(yaw)

    def _place(self, b: Block, s: Seen) -> None:
        b.x, b.y, b.yaw = self._locate(s, b.level, b.size)
        b.pixel_u, b.pixel_v, b.pixel_angle = s.u, s.v, s.angle

    # ------------------------------------------------------------------ updates
    def set_blocks(self, blocks: Iterable[Block]) -> None:
        """Replace the memory (for a known starting configuration)."""
        self.blocks = {b.id: replace(b) for b in blocks}
        self._refresh()

    def update(self, seen: Sequence[Seen]) -> dict[str, str]:
        """Fold one image's detections in. Returns what happened to each block, for logs."""
        events: dict[str, str] = {}
        now = {s.id: s for s in seen}
        moved: set[str] = set()
        for s in seen:
            b = self.blocks.get(s.id)
            if b is None:
                b = Block(s.id, s.color, 0.0, 0.0, 0.0, size=s.size or self.block_size)
                self.blocks[s.id] = b
                self._place(b, s)
                b.rest_frame = self.frame
                b.pose_known = s.complete
                moved.add(s.id)
                events[s.id] = "new"
                continue
            if s.complete:  # a clean view tells upright from on its side; a covered one cannot
                size = s.size or self.block_size
                if stands_upright(size) != b.upright:
                    events[s.id] = "upright" if stands_upright(size) else "on its side"
                b.size = size
                b.pose_known = True
            x, y, yaw = self._locate(s, b.level, b.size)
            tol = (self.params.position_tolerance if s.complete
                   else self.params.occluded_tolerance)
            if math.hypot(x - b.x, y - b.y) > tol:
                moved.add(s.id)
                events[s.id] = "moved"
            else:
                b.rest_frame = self.frame
                if s.complete:  # refine from a clean view; a covered block keeps its pose
                    b.x, b.y, b.yaw = x, y, yaw
            b.pixel_u, b.pixel_v, b.pixel_angle = s.u, s.v, s.angle
        # Nothing rests on a block whose top face is in full view.
        for s in seen:
            if s.complete and s.id not in moved:
                for up in self.above(s.id):
                    if up not in moved:
                        moved.add(up)
                        events.setdefault(up, "lifted")
        # Whatever rested on a block that moved has moved with it or fallen.
        for bid in list(moved):
            for up in self.above(bid):
                if up not in moved:
                    moved.add(up)
                    events.setdefault(up, "toppled")
        for bid in moved:
            self.blocks[bid].support = None
            if not (bid in now and now[bid].complete):  # came to rest unseen or partly covered
                self.blocks[bid].pose_known = False
        self._refresh()
        for bid in moved:  # on the table for now: locate at level 1
            if bid in now:
                self._place(self.blocks[bid], now[bid])
        # A block on the table that covers another block rests on that stack (blocks on one
        # level cannot overlap). Partly covered ones first, so a moved pair lands in order.
        loose = [b.id for b in self.blocks.values() if b.support is None and b.id in now]
        for bid in sorted(loose, key=lambda b: (now[b].complete, b)):
            if self._settle(bid, now):
                events[bid] = f"on {self.blocks[bid].support}"
        # Visibility and missing blocks.
        for b in self.blocks.values():
            b.visible = b.id in now
            if b.visible or not b.on_top:
                b.missing = 0
            else:
                b.missing += 1
                events.setdefault(b.id, "missing")
        if self.params.forget_after > 0:
            for b in list(self.blocks.values()):
                if b.missing >= self.params.forget_after:
                    del self.blocks[b.id]
                    events[b.id] = "forgotten"
        self._refresh()
        self.frame += 1
        return events

    def _settle(self, bid: str, now: Mapping[str, Seen]) -> bool:
        b = self.blocks[bid]
        own = {bid, *self.above(bid)}
        carried = {o.support for o in self.blocks.values() if o.support is not None}
        best = None
        for o in self.blocks.values():
            if o.id in own or o.id in carried:
                continue  # only a stack top can take a block
            if o.id in now and now[o.id].complete:
                continue  # its top face is in full view: nothing is on it
            if o.id not in now and o.missing > 0 and self.frame - o.missing < b.rest_frame:
                # gone while b still rested elsewhere: not something to land on. A block
                # that vanished during b's transit was hidden by the arm carrying b.
                continue
            if footprint_overlap(b, o) >= self.params.cover_fraction and (
                best is None or o.level > best.level
            ):
                best = o
        if best is None:
            return False
        b.support = best.id
        self._refresh()
        if bid in now:
            self._place(b, now[bid])
        return True

    def apply_experience(
        self,
        moved_id: str,
        label: int,
        support_ids: Sequence[str],
        placement_xy: tuple[float, float] | None = None,
        placement_yaw: float | None = None,
    ) -> str:
        """An experiment's outcome: where the moved block ended up, as far as it tells."""
        b = self.blocks.get(moved_id)
        if b is None:
            return f"unknown block {moved_id!r}: ignored"
        for up in self.above(moved_id):  # nothing can have stayed on a block that was moved
            self.blocks[up].support = None
        if label > 0:
            top = support_ids[-1] if support_ids else None
            if top is not None and top not in self.blocks:
                b.support = None
                self._refresh()
                return f"support {top!r} unknown: {moved_id} put on the table"
            if top is not None:
                for o in self.blocks.values():  # whatever memory had put there yields
                    if o.support == top and o.id != moved_id:
                        o.support = None
            b.support = top
            if placement_xy is not None:
                b.x, b.y = placement_xy
            if placement_yaw is not None:
                b.yaw = wrap_quarter(placement_yaw)
            self._refresh()
            if not math.isnan(b.pixel_u) and b.visible:
                self._relocate_from_pixels(b)
            return f"{moved_id} stable on {top or 'the table'} (level {b.level})"
        b.support = None
        self._refresh()
        if not math.isnan(b.pixel_u) and b.visible:
            self._relocate_from_pixels(b)
        return f"{moved_id} fell: on the table"

    def _relocate_from_pixels(self, b: Block) -> None:
        s = Seen(b.id, b.color, b.pixel_u, b.pixel_v, b.pixel_angle, True)
        b.x, b.y, b.yaw = self._locate(s, b.level, b.size)
