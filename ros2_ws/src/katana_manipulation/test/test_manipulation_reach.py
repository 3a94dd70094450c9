"""reach.py against the executor's own planner: inside the band every pick and place plans,
just outside it none does, and the bands shrink with the stack as the arm's geometry says.
The band follows the planner's geometry (grasp_offset, approach_height): checked against a
planner that skips the reach check, so only its inverse kinematics decide."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_description import models as m
from katana_manipulation.core.pick_place import PickPlaceParams, PickPlacePlanner
from katana_manipulation.core.reach import (
    EMPTY,
    pick_reach,
    pick_reach_table,
    place_reach,
    place_reach_table,
)
from katana_manipulation.testing import (
    KinematicsOnly,
    pick_limit_m,
    place_limit_m,
    plans,
)

H = m.BLOCK_SIZE[2]
PLANNER = PickPlacePlanner()
#: a geometry other than the default: the tool grips higher and descends from lower
CHANGED = PickPlaceParams(approach_height=0.045, grasp_offset=0.012)
#: the tool grips lower: the arm must stay farther out to reach down to a block on one
LOWER = PickPlaceParams(grasp_offset=-0.015)


def _plans(pick_r: float, pick_level: int, place_r: float, place_height: int,
           pan: float, planner: PickPlacePlanner = PLANNER) -> tuple[bool, str]:
    return plans(planner, pick_r, pick_level, place_r, place_height, pan)


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


@pytest.mark.parametrize("params", [PickPlaceParams(), CHANGED, LOWER],
                         ids=["default", "changed", "lower"])
@pytest.mark.parametrize("height", [0, 1, 2, 3])
def test_the_band_ends_within_a_centimetre_of_the_planners_limit(height, params):
    geometry = params.geometry
    band = place_reach(height, H, geometry=geometry)
    limit = place_limit_m(params, height, inside=band.max_m)
    assert limit - 0.01 <= band.max_m <= limit
    assert not _plans(0.2, 1, limit + 0.002, height, 0.3, KinematicsOnly(params=params))[0]
    if height < 3:
        pick = pick_reach(height + 1, H, geometry=geometry)
        limit = pick_limit_m(params, height + 1, inside=pick.max_m)
        assert limit - 0.01 <= pick.max_m <= limit
        # and the near edge, where the arm folds too far to reach down
        near = pick_limit_m(params, height + 1, 0.5 * (pick.min_m + pick.max_m), outside=0.0)
        assert near <= pick.min_m <= near + 0.01


def test_the_bands_follow_the_planners_geometry():
    """A higher grip leaves less room above a stack: the bands narrow, and the executor's own
    reach check (with its geometry) refuses what the default geometry allows."""
    default, changed = place_reach_table(3), place_reach_table(3, geometry=CHANGED.geometry)
    assert changed != default
    assert changed[2].max_m < default[2].max_m - 0.01
    r = 0.5 * (changed[2].max_m + default[2].max_m)
    assert _plans(0.2, 1, r, 2, 0.3)[0]
    ok, why = _plans(0.2, 1, r, 2, 0.3, PickPlacePlanner(params=CHANGED))
    assert not ok and "outside the reach" in why
    assert not _plans(0.2, 1, r, 2, 0.3, KinematicsOnly(params=CHANGED))[0]
    # on a stack of three the higher grip leaves no room at all
    assert changed[3].empty and not default[3].empty


def test_no_pick_is_in_reach_when_the_descent_cannot_start_above_the_block():
    """approach_height shorter than the way up to where the open pads clear the block: the
    planner has no descent start, and the reach says so instead of offering a band."""
    low = PickPlaceParams(approach_height=0.03)
    assert all(b == EMPTY for b in pick_reach_table(3, H, geometry=low.geometry))
    planner = KinematicsOnly(params=low)
    for r in np.linspace(0.11, 0.28, 9):  # where the grasp itself is reachable
        ok, why = _plans(float(r), 1, 0.2, 0, 0.3, planner)
        assert not ok and "no room to approach" in why
    assert not place_reach(0, H, geometry=low.geometry).empty  # a place needs less room
