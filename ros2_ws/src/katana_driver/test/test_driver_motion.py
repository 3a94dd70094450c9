"""core.motion's planning rule (ROS-free): merged knots must not bulge past a joint limit."""

import json
from types import SimpleNamespace

import pytest
from katana_description import arm_contract as ac
from katana_driver.core.encoders import EncoderModel
from katana_driver.core.motion import _plan
from katana_driver.core.splines import TrajectoryError, cubic_extremes, plan_trajectory

MODEL = EncoderModel()
# A retreat from pick_place (recorded, first 8 points; the 8th later, to end at rest): the
# wrist lift rises to 0.8 mrad of its upper limit through knots 0.1 s apart. Merged into
# 0.2 s segments, the cubic overshot the stop.
ENCODERS = [8515, -13977, -24451, 4181, 4439, 23296]
TIMES = [0.1, 0.200001, 0.300001, 0.411029, 0.511029, 0.626795, 0.726795, 1.5]
POSITIONS = [
    [-0.266252, 1.063737, -1.279755, 1.354778, 0.266252],
    [-0.266252, 1.077537, -1.193269, 1.455064, 0.266252],
    [-0.266252, 1.083034, -1.094134, 1.559696, 0.266252],
    [-0.266252, 1.078977, -0.97939, 1.670383, 0.266252],
    [-0.266252, 1.069924, -0.891725, 1.748996, 0.266252],
    [-0.266252, 1.054503, -0.792035, 1.833264, 0.266252],
    [-0.266252, 1.08076, -0.776369, 1.875187, 0.266252],
    [-0.266252, 1.33288, -0.961677, 1.875332, 0.266252],
]
VELOCITIES = [
    [0.0, 0.167534, 0.806674, 0.985631, 0.0],
    [0.0, 0.07862, 0.923796, 1.024126, 0.0],
    [0.0, 0.0, 1.01197, 1.021027, 0.0],
    [0.0, -0.052061, 0.948619, 0.879063, 0.0],
    [0.0, -0.107798, 0.868824, 0.755904, 0.0],
    [0.0, 0.0, 0.265081, 0.532042, 0.0],
    [0.0, 0.405671, 0.0, 0.001025, 0.0],
    [0.0, 0.0, 0.0, 0.0, 0.0],
]


def _goal():
    return ac.TrajectoryGoal(list(ac.m.ARM_JOINTS), TIMES, POSITIONS, VELOCITIES)


def test_knots_are_kept_where_merging_them_would_overshoot_a_limit():
    """The knot-keeping rule itself, without the limit margin and with accelerations far above
    KNI's (the recorded goal breaks both; see the next test)."""
    goal = _goal()
    encoders = ENCODERS
    loose = {"limit_margin": 0, "accel_limits": [100] * 5}
    with pytest.raises(TrajectoryError, match="overshoot"):
        plan_trajectory(MODEL, encoders, goal.times_s, goal.positions, goal.velocities,
                        speed_scale=1.02, **loose)
    worker = SimpleNamespace(limit_margin=0, acceleration_limits=[100] * 6,
                             speed_limits=[180] * 6)
    plan = _plan(MODEL, encoders, goal, ac.ArmContract(), worker)
    lo, hi = MODEL.encoder_range(4)
    for row in plan.segments:
        low, high = cubic_extremes(row[3].coefficients(), row[3].duration)
        assert lo <= low and high <= hi
    assert json.dumps(plan.final_angles())  # finite, plain numbers


def test_the_recorded_retreat_is_refused_for_the_limit_margin():
    """The same goal drives the wrist lift to 0.8 mrad (6 encoders) of its limit: a real
    controller is reported to refuse targets within about 200 encoders of a limit, so the
    driver refuses it, naming the joint, the distance and the parameter."""
    goal = _goal()
    with pytest.raises(TrajectoryError, match=(
            r"katana_motor4_lift_joint = 1\.8752 rad is [0-9] encoders from the end of its "
            r"range; targets stay 200 encoders inside it \(limit_margin_encoders\)")):
        _plan(MODEL, ENCODERS, goal, ac.ArmContract())
