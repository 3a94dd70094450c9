"""The fovea (paper section 2.2): states, actions and features of placement locations.

A fovea is a 40x40 pixel window centred on a candidate placement point, turned with the
block it would be placed on (so an action means the same relative placement whatever the
block's yaw). Its state is the height of the tallest stack with pixels in the window (0: no
block pixels, the table). Its features come from the convex hull of that stack's pixels in
the window (for a stack, of the intersection of all its blocks' top faces, Figure 2d): five
points, the centre and (+-r, +-r), are tested against the hull; bits on + 1 is the action
(1..6) and x is the one-hot action followed by a bias of 1.

Block pixels come from the memory (each block's top face re-projected at its level), since
the image shows only the top block of a stack; callers may pass image masks for visible
blocks instead.

The search is the paper's top-down one: for each available state in ascending order, the
fovea moves over a grid around each stack of that height (around free table places for
state 0) and every distinct (state, action) is reported once per stack, with the first
location that realised it; on a stack of two or more, a finer grid then looks for the actions
the grid missed (as `find` does), so the offer holds every action the arm can make there.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from . import fovea_kernels
from .calibration import Calibration
from .memory import Block, top_height
from .segmentation import wrap_quarter

N_POINTS = 5
N_ACTIONS = N_POINTS + 1
ALL_ACTIONS = frozenset(range(1, N_ACTIONS + 1))
_SHIFT = 4
#: a face is drawn within this many pixels of the image origin (in fillPoly's fixed point that
#: fits int32 with room); one reaching beyond is clipped to that square first, which leaves its
#: pixels in the image as they were
_DRAW_LIMIT_PX = float(1 << 20)
_DRAW_BOX = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.float32) * _DRAW_LIMIT_PX
_NOWHERE = np.full((1, 1, 2), -(1 << _SHIFT), np.int32)  # a face that covers no pixel
#: a vertex projected this far (or to no finite point) is not a place on the image: the lens's
#: distortion polynomial far outside the image, or a block nowhere near the camera
_NO_FACE_PX = 1e30
_NO_BITS = (False,) * N_POINTS
_BITS = tuple(tuple(bool(code >> i & 1) for i in range(N_POINTS)) for code in range(1 << N_POINTS))
_ACTION_OF = {bits: sum(bits) + 1 for bits in _BITS}


@dataclass
class FoveaParams:
    size_px: int = 40  # fovea window edge
    offset_px: float = 10.0  # r: the four outer test points sit at (+-r, +-r)
    grid_step_px: float = 6.0  # fovea moves around a stack top on this grid...
    grid_radius_px: float = 36.0  # ...out to this far from its centre (36: action 1 too)
    fine_step_px: float = 2.0  # find_placement's second, finer pass
    table_step_m: float = 0.02  # grid of candidate table places (height 0)
    # (nearest, farthest) placement radius from the pan axis per stack height, m (index =
    # height; the last entry holds above): a taller stack needs the wrist higher, so the arm
    # reaches less far. fovea_node takes these from katana_manipulation.core.reach.
    reach_by_height: tuple[tuple[float, float], ...] = ((0.14, 0.29),)
    area_x: tuple[float, float] = (0.14, 0.30)  # play area, m
    area_y: tuple[float, float] = (-0.16, 0.16)
    clearance: float = 0.005  # free margin around a placed block, m
    max_height: int = 3  # highest stack offered for placement
    table_yaw: float = 0.0  # yaw of blocks placed on the table, rad

    def validate(self) -> None:
        checks = {
            "size_px": 4 <= self.size_px <= 200,
            "offset_px": 0 < self.offset_px < self.size_px / 2,
            "grid_step_px": self.grid_step_px > 0,
            "grid_radius_px": self.grid_radius_px >= 0,
            "fine_step_px": self.fine_step_px > 0,
            "table_step_m": self.table_step_m > 0,
            "reach_by_height": len(self.reach_by_height) > 0 and all(
                len(b) == 2 and 0 <= b[0] < b[1] for b in self.reach_by_height),
            "area_x": self.area_x[0] < self.area_x[1],
            "area_y": self.area_y[0] < self.area_y[1],
            "clearance": self.clearance >= 0,
            "max_height": self.max_height >= 0,
        }
        bad = [k for k, ok in checks.items() if not ok]
        if bad:
            raise ValueError(f"invalid fovea parameters: {', '.join(bad)}")


def probe_points(offset: float) -> np.ndarray:
    """The five points in the fovea frame: centre, then the corners counter-clockwise."""
    r = offset
    return np.array([[0.0, 0.0], [-r, -r], [r, -r], [r, r], [-r, r]])


def action_of(bits: Sequence[bool]) -> int:
    if type(bits) is tuple and (a := _ACTION_OF.get(bits)) is not None:  # the search's bits
        return a
    return int(sum(bool(b) for b in bits)) + 1


def feature_vector(action: int, n_actions: int = N_ACTIONS) -> list[float]:
    """One-hot action followed by a bias of 1 (7 numbers on the robot)."""
    if not 1 <= action <= n_actions:
        raise ValueError(f"action {action} not in 1..{n_actions}")
    x = [0.0] * (n_actions + 1)
    x[action - 1] = 1.0
    x[-1] = 1.0
    return x


def to_fovea_frame(points: np.ndarray, u: float, v: float, angle: float) -> np.ndarray:
    """Image points in the frame of a fovea at (u, v) turned by `angle`. Elementwise, not a
    matrix product: a BLAS kernel may fuse the multiply-adds, and then whether a pixel within
    a rounding of the window's edge is in it would depend on the kernel, not on this formula
    (which fovea_kernels repeats operation for operation)."""
    c, s = math.cos(angle), math.sin(angle)
    d = np.asarray(points, dtype=np.float64) - (u, v)
    return np.column_stack([d[:, 0] * c + d[:, 1] * s, d[:, 0] * -s + d[:, 1] * c])


def in_window(local: np.ndarray, size: float) -> np.ndarray:
    half = size / 2.0
    return ((local[:, 0] >= -half) & (local[:, 0] < half)
            & (local[:, 1] >= -half) & (local[:, 1] < half))


def hull_bits(local: np.ndarray, offset: float) -> tuple[bool, ...]:
    """Point-in-hull tests of the five points against the hull of `local` (fovea frame)."""
    if len(local) < 3:
        return (False,) * N_POINTS
    hull = cv2.convexHull(local.astype(np.float32))
    if cv2.contourArea(hull) < 0.5:  # collinear pixels: no area, nothing is inside
        return (False,) * N_POINTS
    return tuple(
        cv2.pointPolygonTest(hull, (float(px), float(py)), False) >= 0
        for px, py in probe_points(offset)
    )


@dataclass
class Instance:
    """One fovea location and the state-action pair it realises."""

    state: int
    action: int
    bits: tuple[bool, ...]
    features: list[float]
    u: float  # fovea centre in the image, px
    v: float
    angle: float  # fovea frame angle in the image, rad
    x: float  # where the placed block's centre goes, world, m
    y: float
    z: float
    yaw: float
    support_ids: tuple[str, ...]  # the stack under the fovea, bottom first


@dataclass
class _Stack:
    blocks: list[Block]
    union: np.ndarray  # Nx2 pixel coordinates of any of its blocks' top faces
    inter: np.ndarray  # Nx2 pixel coordinates of all of its blocks' top faces
    lo: np.ndarray  # bounding box of `union`
    hi: np.ndarray
    in_inter: np.ndarray  # per pixel of `union`: whether it is in `inter` too

    @property
    def height(self) -> int:
        return len(self.blocks)

    @property
    def top(self) -> Block:
        return self.blocks[-1]

    @property
    def ids(self) -> tuple[str, ...]:
        return tuple(b.id for b in self.blocks)

    @property
    def offered(self) -> bool:
        """A placement is offered on a stack of upright blocks only: one on its side is no
        level of a stack (and the paper's blocks never lie on their side)."""
        return all(b.upright for b in self.blocks)


def _fill(poly: np.ndarray, height: int, width: int) -> np.ndarray:
    m = np.zeros((height, width), dtype=np.uint8)
    cv2.fillPoly(m, poly, 1, lineType=cv2.LINE_8, shift=_SHIFT)
    return m.astype(bool)


def _stack_of(chain: list[Block], masks: list[np.ndarray], x0: int, y0: int) -> _Stack:
    """A stack from its blocks' face masks, whose pixel (0, 0) is image pixel (x0, y0)."""
    union = np.logical_or.reduce(masks)
    inter = np.logical_and.reduce(masks)
    uy, ux = np.nonzero(union)
    iy, ix = np.nonzero(inter)
    upts = np.column_stack([ux + x0, uy + y0]).astype(np.float64)
    ipts = np.column_stack([ix + x0, iy + y0]).astype(np.float64)
    if len(upts):
        lo, hi = upts.min(axis=0), upts.max(axis=0)
    else:
        lo, hi = np.array([np.inf, np.inf]), np.array([-np.inf, -np.inf])
    return _Stack(chain, upts, ipts, lo, hi, inter[uy, ux])


class NotFound(Exception):
    """No fovea location realises the requested state-action pair; the message says why."""


def _top_in_image(c: Calibration, st: _Stack) -> tuple[float, float, float]:
    """Where a stack's top face is in the image: its centre (u, v) and its yaw as an image
    angle, the centre and frame of the fovea's grid around it."""
    top = st.top
    z = top_height(st.height, top.size)
    u0, v0 = (float(a) for a in c.world_to_pixel(top.x, top.y, z))
    return u0, v0, c.yaw_to_image_angle(top.x, top.y, top.yaw, z)


@dataclass
class FoveaScene:
    """The fovea's view of one setting (a memory snapshot)."""

    blocks: Sequence[Block]
    calibration: Calibration
    params: FoveaParams = field(default_factory=FoveaParams)
    masks: Mapping[str, np.ndarray] | None = None  # optional image masks of visible blocks

    def __post_init__(self) -> None:
        self.params.validate()
        self._probes = probe_points(self.params.offset_px)
        self._grids: dict[float, list[tuple[float, float]]] = {}
        by_id = {b.id: b for b in self.blocks}
        above = {b.support: b for b in self.blocks if b.support is not None}
        self.stacks: list[_Stack] = []
        for b in sorted(self.blocks, key=lambda b: b.id):
            if b.support is not None and b.support in by_id:
                continue
            chain = [b]
            while chain[-1].id in above:
                chain.append(above[chain[-1].id])
            self.stacks.append(self._build(chain))
        self.stacks.sort(key=lambda s: s.top.id)
        self._pack()

    def _pack(self) -> None:
        """All stacks' union pixels in one row-major array with per-row start indices, the
        kernel's input: a fovea location reads only the rows its window can reach."""
        rows = max((int(st.union[:, 1].max()) + 1 for st in self.stacks if len(st.union)),
                   default=0)
        xs, inter, starts = [], [], np.zeros((len(self.stacks), rows + 1), np.int64)
        base = 0
        for k, st in enumerate(self.stacks):
            y = st.union[:, 1].astype(np.int64)
            starts[k] = base + np.searchsorted(y, np.arange(rows + 1), side="left")
            xs.append(st.union[:, 0].astype(np.int64))
            inter.append(st.in_inter)
            base += len(y)
        reach = self.params.size_px / math.sqrt(2.0) + 1.0  # as _near
        self._xs = np.concatenate(xs) if xs else np.zeros(0, np.int64)
        self._inter = np.concatenate(inter) if inter else np.zeros(0, bool)
        self._starts = starts
        self._heights = np.array([st.height for st in self.stacks], np.int64)
        self._near_lo = np.array([st.lo - reach for st in self.stacks]).reshape(-1, 2)
        self._near_hi = np.array([st.hi + reach for st in self.stacks]).reshape(-1, 2)

    def _face_poly(self, b: Block, level: int) -> np.ndarray:
        """Block b's top face at `level` in the image, in fillPoly's fixed point (1/16 px); a
        face with a vertex projected to no finite point, or beyond _NO_FACE_PX, covers no
        pixel."""
        poly = self.calibration.square_polygon(b.x, b.y, b.yaw, top_height(level, b.size),
                                               b.size[0], b.size[1])
        if not np.all(np.abs(poly) < _NO_FACE_PX):  # no pixel of the image is any of its
            return _NOWHERE
        if np.abs(poly).max() > _DRAW_LIMIT_PX:  # a block far outside the camera's view
            _, clipped = cv2.intersectConvexConvex(poly.astype(np.float32), _DRAW_BOX)
            if clipped is None or len(clipped) < 3:
                return _NOWHERE
            poly = clipped.reshape(-1, 2).astype(np.float64)
        return np.rint(poly * (1 << _SHIFT)).astype(np.int32).reshape(1, -1, 2)

    def _build(self, chain: list[Block]) -> _Stack:
        """The stack's union and intersection pixels, rasterised in the bounding box of its
        faces only (a whole-image mask per block costs more than the fovea's search): fillPoly's
        fixed-point scanlines shifted by whole pixels give the same pixels, shifted."""
        c = self.calibration
        if self.masks is not None and any(b.id in self.masks for b in chain):
            return _stack_of(chain, [np.asarray(self.masks[b.id], dtype=bool)
                                     if b.id in self.masks else _fill(self._face_poly(b, i + 1),
                                                                      c.height, c.width)
                                     for i, b in enumerate(chain)], 0, 0)
        polys = [self._face_poly(b, i + 1) for i, b in enumerate(chain)]
        pts = np.concatenate(polys, axis=1)[0]
        # a pixel whose centre a face covers lies within its vertices' bounds, rounded out
        x0 = max(0, (int(pts[:, 0].min()) >> _SHIFT) - 2)
        y0 = max(0, (int(pts[:, 1].min()) >> _SHIFT) - 2)
        x1 = min(c.width, (int(pts[:, 0].max()) >> _SHIFT) + 3)
        y1 = min(c.height, (int(pts[:, 1].max()) >> _SHIFT) + 3)
        if x1 <= x0 or y1 <= y0:
            x0 = y0 = x1 = y1 = 0
        shift = np.array([x0 << _SHIFT, y0 << _SHIFT], np.int32)
        return _stack_of(chain, [_fill(p - shift, y1 - y0, x1 - x0) for p in polys], x0, y0)

    # ---------------------------------------------------------------- features
    def features_at(self, u: float, v: float, angle: float) -> tuple[int, _Stack | None, tuple]:
        """(state, the stack under the fovea or None, the five bits) at one fovea location.

        Compiled (fovea_kernels); FoveaSceneReference is the definition it is tested against."""
        if not self.stacks:
            return 0, None, _NO_BITS
        c, s = math.cos(angle), math.sin(angle)
        k, code = fovea_kernels.features_at(
            self._xs, self._inter, self._starts, self._heights, self._near_lo,
            self._near_hi, float(u), float(v), c, s, self.params.size_px / 2.0, self._probes,
            fovea_kernels.TOLERANCE_PX)
        if k < 0:
            return 0, None, _NO_BITS
        st = self.stacks[k]
        if code == fovea_kernels.UNSURE:  # a probe point (almost) on the hull: as the reference
            local = to_fovea_frame(st.inter, u, v, angle)
            return st.height, st, hull_bits(local[in_window(local, self.params.size_px)],
                                            self.params.offset_px)
        return st.height, st, _BITS[code]

    # ---------------------------------------------------------------- checks
    def reach(self, height: int) -> tuple[float, float]:
        """(nearest, farthest) placement radius on a stack of `height`, m."""
        bands = self.params.reach_by_height
        return bands[min(max(height, 0), len(bands) - 1)]

    def _reachable(self, x: float, y: float, height: int = 0) -> bool:
        p = self.params
        e = 1e-9  # a grid point back-projected from its pixel comes back within rounding
        near, far = self.reach(height)
        return (near - e <= math.hypot(x, y) <= far + e
                and p.area_x[0] - e <= x <= p.area_x[1] + e
                and p.area_y[0] - e <= y <= p.area_y[1] + e)

    def _collides(self, x: float, y: float, yaw: float, own: _Stack | None) -> bool:
        p = self.params
        for st in self.stacks:
            if st is own:
                continue
            for b in st.blocks:
                if _overlap_area(x, y, yaw, b.size[0] + 2 * p.clearance,
                                 b.size[1] + 2 * p.clearance, b) > 1e-6:
                    return True
        return False

    def _in_image(self, u: float, v: float) -> bool:
        half = self.params.size_px / 2.0
        c = self.calibration
        return half <= u <= c.width - 1 - half and half <= v <= c.height - 1 - half

    def _instance(self, state: int, bits, u, v, angle, stack: _Stack | None) -> Instance | None:
        c = self.calibration
        h = min(self.blocks[0].size) if self.blocks else 0.03  # one level: an upright block
        z_top = state * h
        x, y = (float(a) for a in c.pixel_to_world(u, v, z_top))
        if not (math.isfinite(x) and math.isfinite(y)) or not self._reachable(x, y, state):
            return None
        yaw = stack.top.yaw if stack is not None else self.params.table_yaw
        if self._collides(x, y, yaw, stack):
            return None
        a = action_of(bits)
        return Instance(
            state=state, action=a, bits=tuple(bits), features=feature_vector(a),
            u=float(u), v=float(v), angle=float(angle), x=x, y=y, z=z_top + h / 2.0,
            yaw=wrap_quarter(yaw), support_ids=stack.ids if stack is not None else (),
        )

    # ---------------------------------------------------------------- scan
    def available_states(self, max_height: int | None = None) -> list[int]:
        """The states (stack heights) this setting offers, 0 (the table) first."""
        cap = self.params.max_height
        if max_height is not None:
            cap = min(max_height, cap)
        return [0] + sorted({st.height for st in self.stacks if st.height <= cap and st.offered})

    def _grid(self, step: float) -> list[tuple[float, float]]:
        r = self.params.grid_radius_px
        n = int(math.floor(r / step + 1e-9))
        offs = [(i * step, j * step) for i in range(-n, n + 1) for j in range(-n, n + 1)]
        return sorted(offs, key=lambda o: (round(math.hypot(*o), 6),
                                           round(math.atan2(o[1], o[0]) % (2 * math.pi), 6)))

    def _around(self, st: _Stack, step: float):
        """Fovea locations around a stack top, in scan order."""
        u0, v0, ang = _top_in_image(self.calibration, st)
        # u0 + du e1 + dv e2 in Python floats: the same IEEE operations as on 2-vectors
        e1u, e1v, e2u, e2v = math.cos(ang), math.sin(ang), -math.sin(ang), math.cos(ang)
        if step not in self._grids:
            self._grids[step] = self._grid(step)
        for du, dv in self._grids[step]:
            yield u0 + du * e1u + dv * e2u, v0 + du * e1v + dv * e2v, ang

    def _table_places(self):
        p = self.params
        xs = np.arange(p.area_x[0], p.area_x[1] + 1e-9, p.table_step_m)
        ys = np.arange(p.area_y[0], p.area_y[1] + 1e-9, p.table_step_m)
        cx, cy = (p.area_x[0] + p.area_x[1]) / 2, (p.area_y[0] + p.area_y[1]) / 2
        pts = [(float(x), float(y)) for x in xs for y in ys]
        pts.sort(key=lambda q: (round(math.hypot(q[0] - cx, q[1] - cy), 6),
                                round(math.atan2(q[1] - cy, q[0] - cx) % (2 * math.pi), 6)))
        c = self.calibration
        for x, y in pts:
            if not self._reachable(x, y):
                continue
            u, v = (float(a) for a in c.world_to_pixel(x, y, 0.0))
            yield u, v, c.yaw_to_image_angle(x, y, p.table_yaw, 0.0)

    def _table_instance(self) -> Instance | None:
        for u, v, ang in self._table_places():
            if not self._in_image(u, v):
                continue
            state, _, bits = self.features_at(u, v, ang)
            if state != 0:
                continue
            inst = self._instance(0, bits, u, v, ang, None)
            if inst is not None:
                return inst
        return None

    def _stack_instances(self, st: _Stack, step: float, want: frozenset[int] = ALL_ACTIONS):
        """The first location of each distinct action of `want` around `st`, in scan order."""
        seen: set[int] = set()
        for u, v, ang in self._around(st, step):
            if not self._in_image(u, v):
                continue
            state, under, bits = self.features_at(u, v, ang)
            if under is not st:
                continue
            a = action_of(bits)
            if a in seen or a not in want:
                continue
            inst = self._instance(state, bits, u, v, ang, st)
            if inst is None:
                continue
            seen.add(a)
            yield inst
            if len(seen) == len(want):
                return

    def observe(self, max_height: int | None = None) -> list[Instance]:
        """Every distinct (state, action) of this setting once per stack, in scan order."""
        out: list[Instance] = []
        for s in self.available_states(max_height):
            if s == 0:
                inst = self._table_instance()
                if inst is not None:
                    out.append(inst)
                continue
            for st in self.stacks:
                if st.height == s and st.offered:
                    out.extend(self._offer_on(st))
        return out

    def _offer_on(self, st: _Stack) -> list[Instance]:
        """Every action a placement on `st` can realise, found as `find` finds it: the grid,
        then the fine grid for the actions the grid missed. An action only the fine grid
        reaches (on a stack, the sliver where exactly one corner leaves the turned top faces'
        intersection) is one the arm can make, so it is offered; otherwise a plan towards it
        would build stacks whose offer never shows it. A single block gets the grid only: its
        face, aligned with the fovea, never realises that action (`feasible_actions`), and a
        search for it would scan the whole fine grid around every loose block."""
        found = list(self._stack_instances(st, self.params.grid_step_px))
        missing = ALL_ACTIONS - {inst.action for inst in found}
        if st.height > 1 and missing and self.params.fine_step_px < self.params.grid_step_px:
            found.extend(self._stack_instances(st, self.params.fine_step_px, want=missing))
        return found

    def find(self, state: int, action: int) -> Instance:
        """The first fovea location realising (state, action), or NotFound with a reason."""
        if not 1 <= action <= N_ACTIONS:
            raise NotFound(f"action {action} does not exist: actions are 1..{N_ACTIONS}")
        states = self.available_states()
        if state not in states:
            if state > self.params.max_height:
                raise NotFound(f"height {state} is above the highest allowed "
                               f"({self.params.max_height})")
            raise NotFound(f"no stack of height {state} in this setting (available: "
                           f"{', '.join(map(str, states))})")
        if state == 0:
            if action != 1:
                raise NotFound("on the table only action 1 exists (no block pixels in the fovea)")
            inst = self._table_instance()
            if inst is None:
                raise NotFound("no free, reachable place on the table")
            return inst
        for step in (self.params.grid_step_px, self.params.fine_step_px):
            for st in self.stacks:
                if st.height != state or not st.offered:
                    continue
                for inst in self._stack_instances(st, step, want=frozenset((action,))):
                    return inst
        raise NotFound(f"no reachable fovea location around a stack of height {state} "
                       f"realises action {action}")


def _overlap_area(x: float, y: float, yaw: float, sx: float, sy: float, b: Block) -> float:
    ra = ((x * 1000, y * 1000), (sx * 1000, sy * 1000), math.degrees(yaw))
    rb = ((b.x * 1000, b.y * 1000), (b.size[0] * 1000, b.size[1] * 1000), math.degrees(b.yaw))
    kind, pts = cv2.rotatedRectangleIntersection(ra, rb)
    if kind == cv2.INTERSECT_NONE or pts is None or len(pts) < 3:
        return 0.0
    return float(cv2.contourArea(cv2.convexHull(pts.reshape(-1, 2).astype(np.float32)))) * 1e-6


class FoveaSceneReference(FoveaScene):
    """The fovea's features as first written, the definition FoveaScene's compiled path is
    tested against (and benchmarked beside): at each location, every pixel of each nearby
    stack is turned into the fovea frame, and OpenCV hulls the intersection pixels in the
    window. Only tests and benches use it."""

    def _face_mask(self, b: Block, level: int) -> np.ndarray:
        c = self.calibration
        if self.masks is not None and b.id in self.masks:
            return np.asarray(self.masks[b.id], dtype=bool)
        return _fill(self._face_poly(b, level), c.height, c.width)

    def _build(self, chain: list[Block]) -> _Stack:
        return _stack_of(chain, [self._face_mask(b, i + 1) for i, b in enumerate(chain)], 0, 0)

    def _around(self, st: _Stack, step: float):
        u0, v0, ang = _top_in_image(self.calibration, st)
        e1 = np.array([math.cos(ang), math.sin(ang)])
        e2 = np.array([-math.sin(ang), math.cos(ang)])
        for du, dv in self._grid(step):
            p = np.array([u0, v0]) + du * e1 + dv * e2
            yield float(p[0]), float(p[1]), ang

    def _near(self, st: _Stack, u: float, v: float) -> bool:
        reach = self.params.size_px / math.sqrt(2.0) + 1.0
        return bool(st.lo[0] - reach <= u <= st.hi[0] + reach
                    and st.lo[1] - reach <= v <= st.hi[1] + reach)

    def features_at(self, u: float, v: float, angle: float) -> tuple[int, _Stack | None, tuple]:
        size = self.params.size_px
        best, best_key = None, None
        for st in self.stacks:
            if not self._near(st, u, v):
                continue
            n = int(in_window(to_fovea_frame(st.union, u, v, angle), size).sum())
            if n == 0:
                continue
            key = (st.height, n)  # ties: the first stack in id order
            if best_key is None or key > best_key:
                best, best_key = st, key
        if best is None:
            return 0, None, (False,) * N_POINTS
        local = to_fovea_frame(best.inter, u, v, angle)
        return best.height, best, hull_bits(local[in_window(local, size)], self.params.offset_px)
