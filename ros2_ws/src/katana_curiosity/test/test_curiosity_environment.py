"""RobotEnvironment's choices that need no graph: where a planned pair is made, and how a
block placed turned is placed and recorded."""

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from katana_curiosity.core.environment import Setting
from katana_curiosity.core.explorer import PLAN, Choice
from katana_curiosity.core.skill import REACH_MARGIN_M
from katana_curiosity.robot_environment import (
    _instance_record,
    leaves_goal_out_of_reach,
    turned,
    within_reach,
)
from katana_interfaces.msg import FoveaInstance
from katana_manipulation.core.reach import place_reach_table

PLACE_REACH_M = tuple((b.min_m, b.max_m) for b in place_reach_table(3, 0.03))


def instance(state: int, action: int, x: float, y: float) -> FoveaInstance:
    inst = FoveaInstance(state=state, action=action)
    inst.placement.position.x, inst.placement.position.y = x, y
    return inst


@given(st.lists(st.tuples(st.floats(0.05, 0.32), st.floats(-math.pi / 2, math.pi / 2)),
                min_size=1, max_size=6),
       st.integers(0, 2), st.integers(1, 3))
def test_a_planned_pair_is_made_where_the_plan_can_go_on_building(spots, state, goal):
    """Of the instances of the planned pair, the first whose placement lies within the place
    reach of every height from the stack it makes up to the plan's goal (1 cm inside), else
    the one nearest to that reach."""
    instances = [instance(state, 1, r * math.cos(a), r * math.sin(a)) for r, a in spots]
    instances.insert(0, instance(state + 1, 2, 0.2, 0.0))  # another pair, first in scan order
    setting = Setting.from_pairs(np.array([i.state for i in instances]),
                                 np.array([i.action - 1 for i in instances]))
    choice = Choice(state, 0, PLAN, 1)
    target = max(goal, state + 1)
    made = within_reach(setting, choice, target, instances, PLACE_REACH_M, 3)
    assert (made.state, made.action, made.mode) == (state, 0, PLAN)
    bands = PLACE_REACH_M[state + 1:target + 1]
    near, far = max(b[0] for b in bands), min(b[1] for b in bands)

    def outside(r):
        return max(near + REACH_MARGIN_M - r, r - (far - REACH_MARGIN_M), 0.0)

    radii = [math.hypot(i.placement.position.x, i.placement.position.y) for i in instances[1:]]
    best = min(outside(r) for r in radii)
    assert outside(radii[made.index - 1]) == best
    assert made.index - 1 == min(k for k, r in enumerate(radii) if outside(r) == best)


@given(st.floats(0.0, 0.35), st.floats(-math.pi, math.pi), st.integers(0, 3),
       st.integers(0, 4))
def test_a_placement_leaves_its_goal_out_of_reach_when_a_height_to_build_cannot_be_placed_on(
        radius, angle, state, goal):
    """Out of reach for the goal exactly when the block, once placed, stands outside the place
    reach of some height from the stack it makes up to the goal (heights the reach table
    lists), each band checked on its own."""
    inst = instance(state, 1, radius * math.cos(angle), radius * math.sin(angle))
    placed = math.hypot(inst.placement.position.x, inst.placement.position.y)
    heights = range(state + 1, min(goal, len(PLACE_REACH_M) - 1) + 1)
    expected = goal > state and any(
        not PLACE_REACH_M[h][0] <= placed <= PLACE_REACH_M[h][1] for h in heights)
    assert leaves_goal_out_of_reach(inst, state, goal, PLACE_REACH_M) == expected
    assert not leaves_goal_out_of_reach(inst, state, goal, ())  # no reach table: never


def _yaw(inst: FoveaInstance) -> float:
    """The placement's yaw by the textbook formula (independent of the code's scipy path)."""
    q = inst.placement.orientation
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


@given(st.floats(-math.pi, math.pi), st.floats(-0.5, 0.5), st.floats(0.1, 0.3),
       st.floats(-0.15, 0.15))
def test_a_turned_placement_differs_from_the_offered_one_by_its_yaw_alone(yaw, turn, x, y):
    offered = instance(2, 6, x, y)
    offered.placement.position.z = 0.09
    offered.placement.orientation.z = math.sin(yaw / 2)
    offered.placement.orientation.w = math.cos(yaw / 2)
    offered.support_ids = ["red", "green"]
    made = turned(offered, turn)
    assert math.isclose(math.remainder(_yaw(made) - _yaw(offered) - turn, 2 * math.pi), 0.0,
                        abs_tol=1e-9)
    assert (made.placement.position.x, made.placement.position.y, made.placement.position.z) \
        == (x, y, 0.09)
    assert list(made.support_ids) == ["red", "green"] and made.action == 6
    assert math.isclose(offered.placement.orientation.z, math.sin(yaw / 2))  # untouched
    record = _instance_record(made, offered)
    assert math.isclose(record.turn_rad, turn, abs_tol=1e-9)
    assert _instance_record(offered, offered).turn_rad == 0.0
