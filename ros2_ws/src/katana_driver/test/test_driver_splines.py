"""Trajectory -> spline segments: passes the knots, respects limits, refuses what it cannot run."""

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from katana_driver.core.encoders import EncoderModel
from katana_driver.core.protocol import INT16_MAX, INT16_MIN
from katana_driver.core.splines import (
    TrajectoryError,
    cubic_extremes,
    cubic_speed_max,
    evaluate,
    plan_trajectory,
)

MODEL = EncoderModel()
HOME = [0.0, 1.2, -1.0, 0.5, 0.0]


def encoders_of(angles):
    return [int(round(MODEL.angle_to_encoder(i + 1, a))) for i, a in enumerate(angles)] + [20000]


def sampled(plan, step_ticks=1.0):
    """Brute force: the commanded encoders at every tick, from the firmware polynomials."""
    rows = []
    for start, segs in zip(plan.start_ticks, plan.segments, strict=True):
        for t in np.arange(0.0, segs[0].duration, step_ticks):
            rows.append([start + t] + [evaluate(s, t) for s in segs])
    last = plan.segments[-1]
    rows.append([plan.total_ticks] + [evaluate(s, s.duration) for s in last])
    return np.array(rows)


def test_plan_passes_through_every_knot_and_ends_on_the_goal():
    times = [1.0, 2.0, 3.5]
    points = [[0.3, 1.4, -0.7, 0.2, 0.4], [0.6, 1.6, -0.4, -0.1, 0.8], [0.8, 1.5, -0.2, -0.3, 0.5]]
    plan = plan_trajectory(MODEL, encoders_of(HOME), times, points)
    assert plan.duration_s == pytest.approx(3.5)
    for t, q in zip(times, points, strict=True):
        assert plan.desired_at(t) == pytest.approx(q, abs=5e-4)
    assert plan.final_angles() == pytest.approx(points[-1], abs=1e-4)
    for segs in plan.segments:  # int16 coefficients, positive durations
        for s in segs:
            assert s.duration > 0
            assert all(INT16_MIN <= v <= INT16_MAX for v in s.values())


def test_segments_join_without_jumps():
    plan = plan_trajectory(MODEL, encoders_of(HOME), [2.0], [[1.0, 1.6, -0.3, 0.0, 1.0]])
    for a, b in zip(plan.segments[:-1], plan.segments[1:], strict=True):
        for sa, sb in zip(a, b, strict=True):
            assert evaluate(sa, sa.duration) == sb.p0


def test_speed_stays_under_the_limit_by_brute_force():
    plan = plan_trajectory(MODEL, encoders_of(HOME), [3.0], [[2.0, 0.2, 1.0, -1.5, 2.5]])
    rows = sampled(plan, 0.25)
    speed = np.abs(np.diff(rows[:, 1:], axis=0)) / np.diff(rows[:, :1], axis=0)
    limits = [MODEL.speed_limit_enc(j + 1) for j in range(5)]
    assert np.all(speed <= np.array(limits) * 1.001)


@pytest.mark.parametrize(
    ("times", "points", "message"),
    [
        ([1.0], [[0.0, 3.0, -1.0, 0.5, 0.0]], "katana_motor2_lift_joint.*outside its limits"),
        ([0.5], [[2.5, 1.2, -1.0, 0.5, 0.0]], "katana_motor1_pan_joint.*rad/s"),
        ([1.0, 1.0], [HOME, HOME], "strictly increasing"),
        ([1.0], [[math.nan, 1.2, -1.0, 0.5, 0.0]], "NaN"),
        ([1.0], [[0.0, 1.2, -1.0]], "shape"),
        ([0.0, 1.0], [[1.0, 1.2, -1.0, 0.5, 0.0], HOME], "from where the arm is"),
        ([], [], "no points"),
    ],
)
def test_refusals_name_the_reason(times, points, message):
    with pytest.raises(TrajectoryError, match=message):
        plan_trajectory(MODEL, encoders_of(HOME), times, points)


def test_given_velocities_that_overshoot_are_refused():
    # Near motor 2's upper limit with a large velocity at the knot: the cubic overshoots.
    with pytest.raises(TrajectoryError):
        plan_trajectory(
            MODEL,
            encoders_of([0.0, 2.0, -1.0, 0.5, 0.0]),
            [1.0, 2.0],
            [[0.0, 2.16, -1.0, 0.5, 0.0], [0.0, 2.0, -1.0, 0.5, 0.0]],
            velocities=[[0.0, 1.1, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0, 0.0]],
        )


def test_dense_knots_are_merged_and_the_goal_kept():
    times = np.linspace(0.05, 2.0, 40)
    points = [[0.5 * t, 1.2, -1.0, 0.5, 0.0] for t in times]
    # without velocities the arm stops at every kept knot: far above KNI's acceleration of 2,
    # which is not what this test is about
    plan = plan_trajectory(MODEL, encoders_of(HOME), times, points, accel_limits=[40] * 5)
    assert all(s[0].duration >= 20 for s in plan.segments[:-1])
    assert plan.final_angles()[0] == pytest.approx(1.0, abs=1e-4)


angles = st.tuples(  # 0.05 rad: over 400 encoders inside every range
    *[st.floats(lo + 0.05, hi - 0.05) for lo, hi in (MODEL.joint_limits(j) for j in range(1, 6))]
)


@settings(max_examples=40, deadline=None)
@given(st.lists(angles, min_size=1, max_size=4))
def test_feasible_random_trajectories_are_planned_and_followed(points):
    # Give every stretch enough time at 80 % of the slowest speed limit and 80 % of KNI's
    # acceleration of 2 encoders per tick^2 (a cubic from rest to rest peaks at 6 d / T^2).
    t, times, prev = 0.0, [], HOME
    for q in points:
        d_enc = max(abs(MODEL.angle_to_encoder(j + 1, a) - MODEL.angle_to_encoder(j + 1, b))
                    for j, (a, b) in enumerate(zip(q, prev, strict=True)))
        t += max(0.3, 1.6 * max(abs(a - b) for a, b in zip(q, prev, strict=True)) / 1.0,
                 math.sqrt(6.0 * d_enc / 1.6) * 0.01)
        times.append(t)
        prev = q
    plan = plan_trajectory(MODEL, encoders_of(HOME), times, [list(q) for q in points])
    assert plan.final_angles() == pytest.approx(list(points[-1]), abs=2e-4)
    rows = sampled(plan, 1.0)
    for j in range(5):  # 200 encoders inside the range, give or take the rounding of p2, p3
        lo, hi = MODEL.encoder_range(j + 1)
        assert np.all(rows[:, 1 + j] >= lo + 200 - 4) and np.all(rows[:, 1 + j] <= hi - 200 + 4)


coef = st.floats(-50, 50, allow_nan=False)


@settings(deadline=None)  # no timed asserts: a loaded machine is not a bug
@given(coef, coef, coef, coef, st.integers(1, 100))
@example(0.0, 0.0, 1.0, 2.225073858507203e-309, 1)  # a subnormal cubic term once broke np.roots
def test_cubic_speed_and_extremes_match_brute_force(c0, c1, c2, c3, duration):
    c2, c3 = c2 / duration, c3 / duration**2
    t = np.linspace(0.0, duration, 4001)
    pos = c0 + c1 * t + c2 * t**2 + c3 * t**3
    vel = c1 + 2 * c2 * t + 3 * c3 * t**2
    scale = 1.0 + abs(c1) + abs(c2) * duration + abs(c3) * duration**2
    assert cubic_speed_max(c1, c2, c3, duration) == pytest.approx(
        np.max(np.abs(vel)), abs=1e-3 * scale
    )
    lo, hi = cubic_extremes((c0, c1, c2, c3), duration)
    assert lo == pytest.approx(pos.min(), abs=1e-3 * scale * duration)
    assert hi == pytest.approx(pos.max(), abs=1e-3 * scale * duration)


def test_a_motor_held_inside_the_margin_is_no_new_target():
    """The arm rests 100 encoders from motor 1's stop (inside the 200-encoder margin): a goal
    that moves the other motors and holds motor 1 there (as a partial goal's completion does)
    is planned; one that sends motor 1 to another point inside the margin is refused."""
    lo, hi = MODEL.encoder_range(1)
    here = MODEL.encoder_to_angle(1, hi - 100)
    start = encoders_of([here, *HOME[1:]])
    moved = [here, HOME[1] + 0.2, *HOME[2:]]
    plan = plan_trajectory(MODEL, start, [2.0], [moved])
    assert all(row[0].target == start[0] for row in plan.segments)
    deeper = MODEL.encoder_to_angle(1, hi - 150)
    with pytest.raises(TrajectoryError, match="limit_margin_encoders"):
        plan_trajectory(MODEL, start, [2.0], [[deeper, *moved[1:]]])
