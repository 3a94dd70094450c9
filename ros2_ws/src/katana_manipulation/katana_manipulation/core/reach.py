"""Reach per stack height, computed once from the kinematics: the one source of "how far".

A top-down pick or place works at a radius r from the pan axis when the tool reaches, pointing
straight down, every height of its vertical move there: for a place, from where the held block
is released up to the lowest start of the descent; for a pick, from the grasp point up to where
the open finger pads clear the block top. Both heights grow with the stack, so a taller stack
is reachable over a narrower annulus. `pick_reach(level)` and `place_reach(height)` give that
annulus (ROS-free, cached); the fovea (where to place) and the curiosity and skill nodes (which
block to move, which stack to build on) use these instead of configured radii, so all of them
agree with what the executor can do.

The heights come from the planner's own settings, a `ReachGeometry` (`PickPlaceParams.geometry`:
the tool point above the block centre when grasping and releasing, the least approach
clearance, the highest start of a descent and the grid it is searched on). Every function takes
one (default: the planner's defaults); the executor checks its goals with its own, and the nodes
that offer placements pass the same parameters (katana_manipulation.reach_params).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

from katana_description import models as m

from .kinematics import KatanaKinematics, Unreachable
from .pick_place_types import DEFAULT_GEOMETRY, ReachGeometry

#: the radial envelope is kept this far inside the kinematic limit, m
MARGIN_M = 0.002
_SCAN_STEP_M = 0.002
_SCAN_MAX_M = 0.8
_HEIGHT_SAMPLES = 5


@dataclass(frozen=True)
class ReachBand:
    """Block-centre radii from the pan axis at which a top-down move works, m (an empty band,
    min_m == max_m == 0, where the move is out of reach at every radius)."""

    min_m: float
    max_m: float

    @property
    def empty(self) -> bool:
        return not self.max_m > self.min_m

    def contains(self, x: float, y: float, tolerance_m: float = 1e-9) -> bool:
        r = math.hypot(x, y)
        return not self.empty and self.min_m - tolerance_m <= r <= self.max_m + tolerance_m


#: no radius works (e.g. picking a block whose top is above the arm's top-down reach)
EMPTY = ReachBand(0.0, 0.0)


def _vertical_ok(kin: KatanaKinematics, r: float, z_low: float, z_high: float) -> bool:
    for k in range(_HEIGHT_SAMPLES):
        z = z_low + (z_high - z_low) * k / (_HEIGHT_SAMPLES - 1)
        try:
            kin.ik_top_down(r, 0.0, z, 0.0, math.pi / 2)
        except Unreachable:
            return False
    return True


def _band(model: str, z_low: float, z_high: float) -> ReachBand:
    """The widest interval of radii whose vertical move [z_low, z_high] is reachable."""
    kin = KatanaKinematics(model)
    n = int(_SCAN_MAX_M / _SCAN_STEP_M)
    ok = [_vertical_ok(kin, k * _SCAN_STEP_M, z_low, z_high) for k in range(n + 1)]
    best: tuple[int, int] | None = None
    start = None
    for k, good in enumerate([*ok, False]):
        if good and start is None:
            start = k
        elif not good and start is not None:
            if best is None or k - start > best[1] - best[0]:
                best = (start, k - 1)
            start = None
    if best is None:
        return EMPTY

    def edge(inside: float, outside: float) -> float:  # bisect the limit to 0.1 mm
        while abs(outside - inside) > 1e-4:
            mid = 0.5 * (inside + outside)
            if _vertical_ok(kin, mid, z_low, z_high):
                inside = mid
            else:
                outside = mid
        return inside

    lo_k, hi_k = best
    lo = lo_k * _SCAN_STEP_M if lo_k == 0 else edge(lo_k * _SCAN_STEP_M,
                                                    (lo_k - 1) * _SCAN_STEP_M)
    hi = edge(hi_k * _SCAN_STEP_M, (hi_k + 1) * _SCAN_STEP_M)
    lo, hi = round(lo + MARGIN_M, 4), round(hi - MARGIN_M, 4)
    return ReachBand(lo, hi) if hi > lo else EMPTY


def _descent_start(z_end: float, lowest: float, g: ReachGeometry) -> float | None:
    """The lowest descent start the planner can pick: on its grid down from approach_height
    above `z_end`, and not below `lowest`; None when approach_height leaves no room above
    `lowest` (the planner then has no start at any radius)."""
    if z_end + g.approach_height < lowest - 1e-9:
        return None
    steps = math.floor((g.approach_height - (lowest - z_end)) / g.approach_step + 1e-9)
    return max(lowest, z_end + g.approach_height - max(steps, 0) * g.approach_step)


def _vertical_band(model: str, z_end: float, lowest: float, g: ReachGeometry) -> ReachBand:
    """Where the vertical move between `z_end` and the planner's descent start works."""
    start = _descent_start(z_end, lowest, g)
    return EMPTY if start is None else _band(model, z_end, start)


def _block_centre(level: int, block_height_m: float, refusal: str) -> float:
    """Height of the centre of a block at `level` (1: on the table), m; ValueError(refusal)
    when there is no such level."""
    if level < 1:
        raise ValueError(refusal)
    return (level - 0.5) * block_height_m


@lru_cache(maxsize=256)
def place_reach(height: int, block_height_m: float = m.BLOCK_SIZE[2],
                model: str = m.DEFAULT_MODEL,
                geometry: ReachGeometry = DEFAULT_GEOMETRY) -> ReachBand:
    """Where a block can be put on a stack of `height` blocks (0: the table)."""
    placed = _block_centre(height + 1, block_height_m, f"height must be >= 0, got {height}")
    z_release = placed + geometry.grasp_offset + geometry.release_clearance
    return _vertical_band(model, z_release, z_release + geometry.min_approach_clearance,
                          geometry)


@lru_cache(maxsize=256)
def pick_reach(level: int, block_height_m: float = m.BLOCK_SIZE[2],
               model: str = m.DEFAULT_MODEL,
               geometry: ReachGeometry = DEFAULT_GEOMETRY) -> ReachBand:
    """Where a block at `level` (1: on the table, 2: on one block, ...) can be picked."""
    centre = _block_centre(level, block_height_m, f"level must be >= 1, got {level}")
    z_grasp = centre + geometry.grasp_offset
    z_clear = (centre + block_height_m / 2 + m.FINGER_PAD_LENGTH / 2
               + geometry.min_approach_clearance)
    return _vertical_band(model, z_grasp, z_clear, geometry)


def place_reach_table(max_height: int, block_height_m: float = m.BLOCK_SIZE[2],
                      model: str = m.DEFAULT_MODEL,
                      geometry: ReachGeometry = DEFAULT_GEOMETRY) -> tuple[ReachBand, ...]:
    """place_reach for heights 0..max_height (index = stack height)."""
    return tuple(place_reach(h, block_height_m, model, geometry) for h in range(max_height + 1))


def pick_reach_table(max_level: int, block_height_m: float = m.BLOCK_SIZE[2],
                     model: str = m.DEFAULT_MODEL,
                     geometry: ReachGeometry = DEFAULT_GEOMETRY) -> tuple[ReachBand, ...]:
    """pick_reach for levels 1..max_level (index = level - 1)."""
    return tuple(pick_reach(level, block_height_m, model, geometry)
                 for level in range(1, max_level + 1))
