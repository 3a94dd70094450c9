"""reach.py against the executor's own planner: inside the band every pick and place plans,
just outside it none does, and the bands shrink with the stack as the arm's geometry says."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_description import models as m
from katana_manipulation.core.pick_place import PickPlacePlanner, PickPlaceRequest, PlanError
from katana_manipulation.core.reach import (
    EMPTY,
    pick_reach,
    place_reach,
    place_reach_table,
)

H = m.BLOCK_SIZE[2]
PLANNER = PickPlacePlanner()
START = np.asarray(m.PARK_POSE, float)


def _plans(pick_r: float, pick_level: int, place_r: float, place_height: int,
           pan: float) -> tuple[bool, str]:
    req = PickPlaceRequest(
        pick=(pick_r * math.cos(pan), pick_r * math.sin(pan), (pick_level - 0.5) * H),
        pick_yaw=0.0, block_size=m.BLOCK_SIZE,
        place=(place_r * math.cos(-pan), place_r * math.sin(-pan), (place_height + 0.5) * H),
        place_yaw=0.0)
    try:
        PLANNER.plan(req, START)
    except PlanError as exc:
        return False, str(exc)
    return True, ""


def test_bands_shrink_with_the_stack_and_the_top_level_is_out_of_reach():
    table = place_reach_table(3)
    assert len(table) == 4
    assert all(not b.empty for b in table)
    maxima = [b.max_m for b in table]
    assert maxima == sorted(maxima, reverse=True)
    # the arm's top-down tool reaches about 0.128 m high: a block on a stack of three is out
    assert pick_reach(4) == EMPTY and not EMPTY.contains(0.2, 0.0)
    with pytest.raises(ValueError):
        place_reach(-1)
    with pytest.raises(ValueError):
        pick_reach(0)


@settings(max_examples=40, deadline=None)
@given(height=st.integers(0, 3), frac=st.floats(0.0, 1.0), pan=st.floats(-1.0, 1.0))
def test_every_place_inside_the_band_plans(height, frac, pan):
    band = place_reach(height)
    r = band.min_m + frac * (band.max_m - band.min_m)
    ok, why = _plans(0.2, 1, r, height, pan)
    assert ok, (height, r, why)


@settings(max_examples=30, deadline=None)
@given(level=st.integers(1, 3), frac=st.floats(0.0, 1.0), pan=st.floats(-1.0, 1.0))
def test_every_pick_inside_the_band_plans(level, frac, pan):
    band = pick_reach(level)
    r = band.min_m + frac * (band.max_m - band.min_m)
    ok, why = _plans(r, level, 0.2, 0, pan)
    assert ok, (level, r, why)


def _planner_limit(plans, inside: float, outside: float = 0.6) -> float:
    """The farthest radius the planner itself accepts, by bisection (the independent check)."""
    while outside - inside > 5e-4:
        mid = 0.5 * (inside + outside)
        inside, outside = (mid, outside) if plans(mid) else (inside, mid)
    return inside


@pytest.mark.parametrize("height", [0, 1, 2, 3])
def test_the_band_ends_within_a_centimetre_of_the_planners_limit(height):
    band = place_reach(height)
    limit = _planner_limit(lambda r: _plans(0.2, 1, r, height, 0.3)[0], band.max_m)
    assert limit - 0.01 <= band.max_m <= limit
    assert not _plans(0.2, 1, limit + 0.002, height, 0.3)[0]
    if height < 3:
        pick = pick_reach(height + 1)
        limit = _planner_limit(lambda r: _plans(r, height + 1, 0.2, 0, 0.3)[0], pick.max_m)
        assert limit - 0.01 <= pick.max_m <= limit
