"""The least motion time on a joint-space path under per-joint speed and acceleration limits
(katana_manipulation.core.time_optimal), against closed forms and bounds computed apart from it,
and the pick-and-place planner's timing within 1.5 times that least time (ROS-free)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_description import models as m
from katana_manipulation.core import pick_place as pp
from katana_manipulation.core.time_optimal import (
    minimum_time,
    reachable_speeds_reference,
    time_optimal,
)
from katana_manipulation.core.time_optimal_kernels import reachable_speeds

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib
from planned_requests import reachable_requests  # noqa: E402

#: the arm contract's limits, from the vendor numbers: rad/s, and KNI's 2 encoders per 10 ms
#: tick squared over the encoders per radian of docs/KATANA.md
SPEED = np.array([m.JOINT_MAX_SPEED[j] for j in m.ARM_JOINTS])
ACCEL = 2.0 / (np.array([51200, 94976, 47488, 51200, 51200]) / (2.0 * math.pi)) / 0.01**2
PLANNER = pp.PickPlacePlanner()


def _trapezoid(d: float, v: float, a: float) -> float:
    """Rest to rest over distance d: accelerate, cruise at v if it is reached, brake."""
    return d / v + v / a if d >= v * v / a else 2.0 * math.sqrt(d / a)


def _line_time(d: np.ndarray, v: np.ndarray, a: np.ndarray) -> float:
    """A straight joint-space move: the path speed and acceleration its slowest joints allow."""
    length = float(np.linalg.norm(d))
    moving = np.abs(d) > 0
    return _trapezoid(length, float(np.min(v[moving] * length / np.abs(d[moving]))),
                      float(np.min(a[moving] * length / np.abs(d[moving]))))


_angle = st.floats(-3.0, 3.0).map(lambda x: round(x, 3))  # milliradians: no subnormal moves
_move = st.lists(_angle, min_size=5, max_size=5).map(np.array).filter(
    lambda d: np.linalg.norm(d) > 1e-3)
_limits = st.tuples(st.lists(st.floats(0.2, 3.0), min_size=5, max_size=5),
                    st.lists(st.floats(0.2, 3.0), min_size=5, max_size=5))


@settings(max_examples=60, deadline=None)
@given(d=_move, limits=_limits, pieces=st.integers(1, 4))
def test_a_straight_move_takes_the_trapezoid_time_in_any_number_of_pieces(d, limits, pieces):
    v, a = (np.array(x) for x in limits)
    q0 = np.zeros(5)
    points = [q0 + d * k / pieces for k in range(pieces + 1)]
    expected = _line_time(d, v, a)
    assert minimum_time(points, v, a, grid_per_segment=200) == \
        pytest.approx(expected, rel=5e-3)


@settings(max_examples=30, deadline=None)
@given(d=_move, limits=_limits)
def test_out_and_back_stops_at_the_turn(d, limits):
    """Every joint turns back at the far point, so it must stop there: two trapezoids."""
    v, a = (np.array(x) for x in limits)
    q0 = np.zeros(5)
    got = minimum_time([q0, d, q0], v, a, grid_per_segment=200)
    assert abs(got / (2.0 * _line_time(d, v, a)) - 1.0) < 0.02


def _per_joint_bound(points: np.ndarray, v: np.ndarray, a: np.ndarray) -> float:
    """A lower bound apart from the path: each joint must stop wherever it turns back, and no
    run between turns is quicker than its trapezoid."""
    best = 0.0
    for j in range(points.shape[1]):
        x = points[:, j]
        dx = np.diff(x)
        dx = dx[np.abs(dx) > 0]
        runs, total = [], 0.0
        for k, step in enumerate(dx):
            if k and np.sign(step) != np.sign(dx[k - 1]):
                runs.append(total)
                total = 0.0
            total += abs(step)
        runs.append(total)
        best = max(best, sum(_trapezoid(r, v[j], a[j]) for r in runs if r > 0))
    return best


@settings(max_examples=40, deadline=None)
@given(points=st.lists(st.lists(_angle, min_size=5, max_size=5), min_size=2,
                       max_size=6).map(np.array).filter(
                           lambda p: np.all(np.linalg.norm(np.diff(p, axis=0), axis=1) > 1e-2)))
def test_the_optimal_motion_keeps_the_limits_and_no_joint_could_be_quicker(points):
    """Sampled every controller tick (constant path acceleration between grid points), the
    motion keeps every limit, give or take the grid; and it takes no less than each joint alone
    would need."""
    prof = time_optimal(points, SPEED, ACCEL, grid_per_segment=200)
    assert np.allclose(prof.path(prof.s[[0, -1]]), points[[0, -1]])
    ts = np.arange(0.0, prof.duration, 0.01)
    i = np.clip(np.searchsorted(prof.t, ts, side="right") - 1, 0, len(prof.s) - 2)
    u = (prof.sdot[i + 1] ** 2 - prof.sdot[i] ** 2) / (2.0 * (prof.s[i + 1] - prof.s[i]))
    tau = ts - prof.t[i]
    q = prof.path(np.minimum(prof.s[i] + prof.sdot[i] * tau + 0.5 * u * tau**2, prof.s[-1]))
    assert np.all(np.abs(np.diff(q, axis=0)) / 0.01 <= SPEED * 1.01)
    assert np.all(np.abs(np.diff(q, 2, axis=0)) / 0.01**2 <= ACCEL * 1.05)
    assert prof.duration >= _per_joint_bound(points, SPEED, ACCEL) * 0.995


_passes_input = st.integers(1, 40).flatmap(lambda n: st.tuples(
    st.lists(st.lists(st.one_of(st.floats(-4.0, 4.0), st.sampled_from([0.0, 1e-9, 2e-9, -0.0])),
                      min_size=10, max_size=10), min_size=n, max_size=n),
    st.lists(st.lists(st.floats(0.0, 5.0), min_size=10, max_size=10), min_size=n, max_size=n),
    st.lists(st.lists(st.booleans(), min_size=10, max_size=10), min_size=n, max_size=n),
    st.lists(st.one_of(st.floats(0.0, 50.0), st.sampled_from([math.inf, -0.0])), min_size=n + 1,
             max_size=n + 1)))


@settings(max_examples=200, deadline=None)
@given(arrays=_passes_input)
def test_the_compiled_passes_equal_their_reference_bit_for_bit(arrays):
    """The compiled reachability passes against their plain-Python twin: the same float64
    bits (a -0.0 too), whatever the rows, bounds and unbounded points."""
    g, step, moving, xmax = (np.array(a, dtype=t) for a, t in
                             zip(arrays, (float, float, bool, float), strict=True))
    fast = reachable_speeds(g, step, moving, xmax, 1e-9)
    assert fast.tobytes() == reachable_speeds_reference(g, step, moving, xmax).tobytes()


def _motion(segments) -> tuple[float, float]:
    """(planned, least) seconds of arm motion of a plan, the least on each move's own path."""
    planned = least = 0.0
    for seg in segments:
        if seg.kind == "arm":
            planned += seg.times[-1]
            least += minimum_time([seg.start, *seg.waypoints], SPEED, ACCEL)
    return planned, least


@settings(max_examples=30, deadline=None)
@given(req=reachable_requests())
def test_a_pick_and_place_moves_within_one_and_a_half_times_the_least_time(req):
    if req is None:
        return
    try:
        segments = PLANNER.plan(req, m.PARK_POSE)
    except pp.PlanError:
        return
    planned, least = _motion(segments)
    assert least > 0.0
    assert planned <= 1.5 * least, (planned, least)
    again = pp.PickPlacePlanner().plan(req, m.PARK_POSE)  # deterministic
    assert [(s.times, s.points, s.velocities) for s in again] == \
        [(s.times, s.points, s.velocities) for s in segments]


class _CountingPlanner(pp.PickPlacePlanner):
    """The planner, counting its calls of `timed`."""

    calls = 0

    def timed(self, start, points):
        self.calls += 1
        return super().timed(start, points)


@settings(max_examples=25, deadline=None)
@given(reachable_requests())
def test_each_planned_move_is_timed_once_on_its_own_waypoints(req):
    """The plan times each trajectory it runs once, merged moves included, and no move it does
    not run; each is what `timed` makes of its waypoints from where it starts."""
    if req is None:
        return
    planner = _CountingPlanner()
    try:
        segs = planner.plan(req, m.PARK_POSE)
    except pp.PlanError:
        return
    moves = [s for s in segs if s.kind == "arm"]
    assert planner.calls == len(moves)
    assert any(s.also for s in moves)  # approach runs into descend, retreat into park
    for s in moves:
        assert (s.points, s.times, s.velocities) == PLANNER.timed(s.start, s.waypoints)
        assert s.points and np.allclose(s.points[-1], s.waypoints[-1], atol=1e-3)
