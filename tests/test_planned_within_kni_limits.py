"""Every arm trajectory the pick-and-place planner makes is one the Katana driver accepts: its
targets stay limit_margin_encoders (200) inside every encoder range and its acceleration within
KNI's limit (2 encoders per 10 ms tick squared), checked by the driver's own planner and, apart
from it, by finite differences of the trajectory sampled densely (ROS-free)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_description import arm_contract as ac
from katana_description import models as m
from katana_driver.core.encoders import EncoderModel
from katana_driver.core.splines import TrajectoryError, plan_trajectory
from katana_manipulation.core import pick_place as pp
from scipy.interpolate import CubicHermiteSpline

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib
from planned_requests import reachable_requests  # noqa: E402

MODEL = EncoderModel()
CONTRACT = ac.ArmContract()
PLANNER = pp.PickPlacePlanner()
#: independent of the code under test: docs/KATANA.md's encoder ticks per revolution, the
#: ROS 1 node's acceleration limit and the driver's default margin
TICKS_PER_REV = np.array([51200, 94976, 47488, 51200, 51200])
ENC_PER_RAD = TICKS_PER_REV / (2.0 * math.pi)
ACCEL_ENC_PER_TICK2 = 2.0
MARGIN_ENC = 200.0
ACCEL_RAD_S2 = ACCEL_ENC_PER_TICK2 / ENC_PER_RAD / 0.01**2
LOWER = np.array([m.JOINT_LIMITS[j][0] for j in m.ARM_JOINTS])
UPPER = np.array([m.JOINT_LIMITS[j][1] for j in m.ARM_JOINTS])
SPEED = np.array([m.JOINT_MAX_SPEED[j] for j in m.ARM_JOINTS])
DT = 0.001  # s between samples of the goal's spline


def _start_encoders(q, offset) -> list[int]:
    """Where the driver starts a goal from: the pose in encoders, a few encoders off (a motor
    holding short of its last target)."""
    return [int(round(MODEL.angle_to_encoder(j + 1, q[j]))) + offset[j] for j in range(5)]


def _driver_accepts(seg: pp.Segment, start, offset) -> None:
    """The driver's own checks: the arm contract and its spline planner, with its defaults."""
    current = dict(zip(m.ARM_JOINTS, start, strict=True))
    goal = ac.TrajectoryGoal(list(m.ARM_JOINTS), seg.times, seg.points, seg.velocities)
    verdict = ac.validate_trajectory(goal, current, CONTRACT)
    assert verdict.ok, (seg.phase, verdict)
    try:
        plan = plan_trajectory(MODEL, _start_encoders(start, offset), seg.times, seg.points,
                               seg.velocities, speed_scale=CONTRACT.speed_margin,
                               limit_margin=200, accel_limits=[2] * 5,
                               firmware_speed_limits=[180] * 5)
    except TrajectoryError as exc:
        raise AssertionError(f"{seg.phase}: the driver refuses it: {exc}") from None
    # what the controller plays, tick by tick along each segment's cubic (its coefficients
    # as sent, rounded to 16 bits): the speed changes by at most the limit, give or take
    # that rounding
    for row in plan.segments:
        for segment in row:
            c0, c1, c2, c3 = segment.coefficients()
            t = np.arange(0, segment.duration + 1, dtype=float)
            enc = c0 + c1 * t + c2 * t**2 + c3 * t**3
            assert np.max(np.abs(np.diff(enc, 2))) <= ACCEL_ENC_PER_TICK2 * 1.01 + 0.01


def _sampled_within_limits(seg: pp.Segment, start) -> None:
    """The goal as both backends follow it (cubic Hermite through the points, from rest at
    the start), sampled every millisecond: every sample 200 encoders inside the range, and
    the finite-difference speed and acceleration within the limits."""
    t = np.concatenate([[0.0], seg.times])
    q = np.vstack([start, seg.points])
    v = np.vstack([np.zeros(5), seg.velocities])
    ts = np.arange(0.0, t[-1], DT)
    pos = CubicHermiteSpline(t, q, v, axis=0)(ts)
    inside = np.minimum(pos - LOWER, UPPER - pos) * ENC_PER_RAD
    assert np.min(inside) >= MARGIN_ENC - 1e-6, (seg.phase, np.min(inside, axis=0))
    speed = np.abs(np.diff(pos, axis=0)) / DT
    assert np.all(speed <= SPEED * CONTRACT.speed_margin + 1e-6), seg.phase
    accel = np.abs(np.diff(pos, 2, axis=0)) / DT**2
    worst = np.max(accel, axis=0) / ACCEL_RAD_S2
    assert np.all(worst <= 1.0 + 1e-3), (seg.phase, worst)


def _check(segments, start, offset) -> int:
    moves = 0
    for seg in segments:
        if seg.kind != "arm":
            continue
        _sampled_within_limits(seg, start)
        _driver_accepts(seg, start, offset)
        start = np.asarray(seg.points[-1], float)
        moves += 1
    return moves


_offsets = st.lists(st.integers(-3, 3), min_size=5, max_size=5)


@settings(max_examples=40, deadline=None)
@given(req=reachable_requests(), offset=_offsets)
def test_every_planned_pick_and_place_is_one_the_driver_accepts(req, offset):
    if req is None:
        return
    try:
        segments = PLANNER.plan(req, m.PARK_POSE)
    except pp.PlanError as exc:  # in reach, yet the inverse kinematics of its yaw may fail
        assert exc.code in (pp.PICK_UNREACHABLE, pp.PLACE_UNREACHABLE, pp.UNREACHABLE)
        return
    # three trajectories: approach and descent, lift to lower, retreat and park
    assert _check(segments, np.asarray(m.PARK_POSE, float), offset) == 3


def _anywhere(margin_rad: float = 0.0):
    return st.tuples(*(st.floats(lo + margin_rad, hi - margin_rad)
                       for lo, hi in zip(LOWER, UPPER, strict=True)))


@settings(max_examples=40, deadline=None)
@given(start=_anywhere(), offset=_offsets)
def test_the_way_to_the_park_pose_is_one_the_driver_accepts(start, offset):
    """After a failure the arm parks from wherever it is: even from inside the margin (where
    the driver's calibration back-off leaves it) every target keeps the margin."""
    start = np.asarray(start, float)
    segments = PLANNER.park_segments(start)
    for seg in segments:
        _driver_accepts(seg, start, offset)
    inside = np.minimum(np.asarray(m.PARK_POSE) - LOWER, UPPER - np.asarray(m.PARK_POSE))
    assert np.all(inside * ENC_PER_RAD >= MARGIN_ENC)


def test_an_unlimited_plan_would_be_refused():
    """The checks above can fail: timed for the speed limits alone (the planner before the
    acceleration limit), a pick and place asks the controller for more than 2 encoders per
    tick squared, and the driver refuses it."""
    fast = pp.PickPlacePlanner(params=pp.PickPlaceParams(accel_fraction=50.0))
    req = pp.PickPlaceRequest((0.22, -0.08, 0.015), 0.4, m.BLOCK_SIZE, (0.18, 0.1, 0.045), -0.7)
    seg = next(s for s in fast.plan(req, m.PARK_POSE) if s.kind == "arm")
    try:
        _driver_accepts(seg, np.asarray(m.PARK_POSE, float), [0] * 5)
    except AssertionError as exc:
        assert "acceleration" in str(exc) or "accelerate" in str(exc)
    else:
        raise AssertionError("a plan timed for speed alone passed the acceleration check")
