"""The sim's scatter against the arm's reach: every block a reset scatters can be picked, with
room for perception's error, so that the robot loop does not reset again at once because a
block it perceives lies just beyond the pick reach."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_manipulation.core.reach import pick_reach
from katana_sim.core import PhysicsSim, SimConfig

#: how far perception may place a block from where it lies, m
PERCEPTION_ERROR_M = 0.005


def test_the_scatter_area_lies_inside_the_pick_reach_of_a_table_block() -> None:
    band = pick_reach(1)
    low, high = SimConfig().play_radius
    assert band.min_m + PERCEPTION_ERROR_M <= low
    assert high + PERCEPTION_ERROR_M <= band.max_m


@pytest.fixture(scope="module")
def world():
    sim = PhysicsSim(SimConfig())
    yield sim
    sim.close()


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 2))
def test_every_scattered_block_can_be_picked(world, seed: int) -> None:
    band = pick_reach(1)
    for x, y, _ in world.scatter_poses(seed):
        radius = math.hypot(x, y)
        assert band.min_m + PERCEPTION_ERROR_M <= radius <= band.max_m - PERCEPTION_ERROR_M
