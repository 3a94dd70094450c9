"""Reach per stack height, computed once from the kinematics: the one source of "how far".

A top-down pick or place works at a radius r from the pan axis when the tool reaches, pointing
straight down, every height of its vertical move there: for a place, from where the held block
is released up to the lowest start of the descent; for a pick, from the grasp point up to where
the open finger pads clear the block top. Both heights grow with the stack, so a taller stack
is reachable over a narrower annulus. `pick_reach(level)` and `place_reach(height)` give that
annulus (ROS-free, cached); the fovea (where to place) and the curiosity node (which block to
move) use these instead of configured radii, so all of them agree with what the executor can do.

The clearances mirror the executor's planner (`PickPlaceParams` in pick_place.py): the tool
point above the block centre when grasping and releasing, and the least approach clearance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

from katana_description import models as m

from .kinematics import KatanaKinematics, Unreachable

#: tool point above the block centre when grasping (PickPlaceParams.grasp_offset), m
GRASP_OFFSET_M = 0.003
#: block bottom above its support when released (PickPlaceParams.release_clearance), m
RELEASE_CLEARANCE_M = 0.002
#: least clearance of a descent's start above the block (min_approach_clearance), m
APPROACH_CLEARANCE_M = 0.008
#: a descent starts at most this far above the grasp or release point (approach_height), m
APPROACH_HEIGHT_M = 0.06
#: the planner looks for a descent's start on a grid of this step, down from approach_height
APPROACH_SEARCH_STEP_M = 0.004
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


def _descent_start(z_end: float, lowest: float) -> float:
    """The lowest descent start the planner can pick: on its grid down from approach_height
    above `z_end`, and not below `lowest`."""
    steps = math.floor((APPROACH_HEIGHT_M - (lowest - z_end)) / APPROACH_SEARCH_STEP_M + 1e-9)
    return max(lowest, z_end + APPROACH_HEIGHT_M - max(steps, 0) * APPROACH_SEARCH_STEP_M)


@lru_cache(maxsize=64)
def place_reach(height: int, block_height_m: float = m.BLOCK_SIZE[2],
                model: str = m.DEFAULT_MODEL) -> ReachBand:
    """Where a block can be put on a stack of `height` blocks (0: the table)."""
    if height < 0:
        raise ValueError(f"height must be >= 0, got {height}")
    centre = (height + 0.5) * block_height_m
    z_release = centre + GRASP_OFFSET_M + RELEASE_CLEARANCE_M
    return _band(model, z_release, _descent_start(z_release, z_release + APPROACH_CLEARANCE_M))


@lru_cache(maxsize=64)
def pick_reach(level: int, block_height_m: float = m.BLOCK_SIZE[2],
               model: str = m.DEFAULT_MODEL) -> ReachBand:
    """Where a block at `level` (1: on the table, 2: on one block, ...) can be picked."""
    if level < 1:
        raise ValueError(f"level must be >= 1, got {level}")
    centre = (level - 0.5) * block_height_m
    z_grasp = centre + GRASP_OFFSET_M
    z_clear = centre + block_height_m / 2 + m.FINGER_PAD_LENGTH / 2 + APPROACH_CLEARANCE_M
    return _band(model, z_grasp, _descent_start(z_grasp, z_clear))


def place_reach_table(max_height: int, block_height_m: float = m.BLOCK_SIZE[2],
                      model: str = m.DEFAULT_MODEL) -> tuple[ReachBand, ...]:
    """place_reach for heights 0..max_height (index = stack height)."""
    return tuple(place_reach(h, block_height_m, model) for h in range(max_height + 1))
