"""RobotEnvironment's choices that need no graph: where a planned pair is made."""

import math
from types import SimpleNamespace

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from katana_curiosity.core.environment import Setting
from katana_curiosity.core.explorer import PLAN, Choice
from katana_curiosity.core.skill import REACH_MARGIN_M
from katana_curiosity.robot_environment import RobotEnvironment
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
    env = SimpleNamespace(instances=instances, config=SimpleNamespace(
        max_height=3, place_reach_m=PLACE_REACH_M))
    setting = Setting.from_pairs(np.array([i.state for i in instances]),
                                 np.array([i.action - 1 for i in instances]))
    choice = Choice(state, 0, PLAN, 1)
    target = max(goal, state + 1)
    made = RobotEnvironment.place_planned(env, setting, choice, target)
    assert (made.state, made.action, made.mode) == (state, 0, PLAN)
    bands = PLACE_REACH_M[state + 1:target + 1]
    near, far = max(b[0] for b in bands), min(b[1] for b in bands)

    def outside(r):
        return max(near + REACH_MARGIN_M - r, r - (far - REACH_MARGIN_M), 0.0)

    radii = [math.hypot(i.placement.position.x, i.placement.position.y) for i in instances[1:]]
    best = min(outside(r) for r in radii)
    assert outside(radii[made.index - 1]) == best
    assert made.index - 1 == min(k for k, r in enumerate(radii) if outside(r) == best)
