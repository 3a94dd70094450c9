"""The arm contract: property-based tests of goal validation and completion (ROS-free)."""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_description import arm_contract as ac
from katana_description import gripper_contract as gc
from katana_description import models as m

CONTRACT = ac.ArmContract()
REST = {n: 0.5 * (m.JOINT_LIMITS[n][0] + m.JOINT_LIMITS[n][1]) for n in m.ARM_JOINTS}
ACTION = (
    Path(__file__).resolve().parents[2]
    / "control_msgs"
    / "action"
    / "FollowJointTrajectory.action"
)


#: independent of the contract: the controller's acceleration limit, 2 encoders per 10 ms tick
#: squared, in rad/s^2 from each motor's encoder ticks per revolution (docs/KATANA.md), and the
#: 200-encoder margin in rad
TICKS_PER_REV = (51200, 94976, 47488, 51200, 51200)
ACCEL = {n: 2.0 / (t / (2.0 * math.pi)) / 0.01**2 for n, t in zip(m.ARM_JOINTS, TICKS_PER_REV,
                                                                   strict=True)}
MARGIN_RAD = {n: 200.0 / (t / (2.0 * math.pi)) for n, t in zip(m.ARM_JOINTS, TICKS_PER_REV,
                                                               strict=True)}


def _within(name: str, margin: bool = False):
    """Angles within the joint limits (``margin``: within the targets' limits, 200 encoders in)."""
    lo, hi = m.JOINT_LIMITS[name]
    d = MARGIN_RAD[name] * 1.0001 if margin else 0.0
    return st.floats(lo + d, hi - d, allow_nan=False)


@st.composite
def valid_goals(draw, partial: bool = True):
    """Goals that obey every rule: targets 200 encoders inside the joint limits (where the arm
    is need not be), segments slow enough at rest (speed and acceleration)."""
    names = list(m.ARM_JOINTS)
    if partial:
        names = draw(st.lists(st.sampled_from(m.ARM_JOINTS), min_size=1, max_size=5, unique=True))
    current = {n: draw(_within(n)) for n in m.ARM_JOINTS}
    n_points = draw(st.integers(1, 4))
    rows = [[draw(_within(n, margin=True)) for n in names] for _ in range(n_points)]
    times, prev, t = [], [current[n] for n in names], 0.0
    for row in rows:
        # at rest at both ends a Hermite segment peaks at 1.5 x its mean speed and at
        # 6 d / h^2 acceleration (at both ends)
        need = max(
            max(1.5 * abs(q - p) / m.JOINT_MAX_SPEED[n], math.sqrt(6.0 * abs(q - p) / ACCEL[n]))
            for n, q, p in zip(names, row, prev, strict=True)
        )
        t += max(need * draw(st.floats(1.0, 3.0)), 0.01)
        times.append(t)
        prev = row
    tol = {n: draw(st.floats(-1.0, 0.5, allow_nan=False)) for n in names[:2]}
    goal = ac.TrajectoryGoal(
        names,
        times,
        rows,
        None,
        path_tolerance={},
        goal_tolerance=tol,
        goal_time_tolerance_s=draw(st.floats(0.0, 5.0)),
    )
    return goal, current


def test_codes_equal_the_interface_constants():
    text = ACTION.read_text()
    found = dict(re.findall(r"int32 ([A-Z_]+) *= *(-?\d+)", text))
    assert found, "no constants parsed from the .action file"
    for name, value in found.items():
        assert getattr(ac, name) == int(value), name


@settings(max_examples=200, deadline=None)
@given(valid_goals())
def test_valid_goals_are_accepted(case):
    goal, current = case
    assert ac.validate_trajectory(goal, current, CONTRACT) == ac.OK


@settings(max_examples=50, deadline=None)
@given(valid_goals(), st.lists(st.text(max_size=8), min_size=1, max_size=3))
def test_goals_with_multi_dof_parts_are_refused(case, multi_dof):
    """The Katana has no multi-DOF joint: a goal naming one is refused, not half run."""
    goal, current = case
    goal = dataclasses.replace(goal, multi_dof_joints=multi_dof)
    verdict = ac.validate_trajectory(goal, current, CONTRACT)
    assert verdict.error_code == ac.INVALID_JOINTS
    assert "multi-DOF" in verdict.error_string


@settings(max_examples=100, deadline=None)
@given(valid_goals())
def test_completion_holds_the_joints_a_partial_goal_leaves_out(case):
    goal, current = case
    full = ac.complete_trajectory(goal, current)
    assert list(full.joint_names) == list(m.ARM_JOINTS)
    for row_in, row_out in zip(goal.positions, full.positions, strict=True):
        for j, n in enumerate(m.ARM_JOINTS):
            expected = row_in[goal.joint_names.index(n)] if n in goal.joint_names else current[n]
            assert row_out[j] == expected
    assert ac.validate_trajectory(full, current, CONTRACT) == ac.OK


@settings(max_examples=200, deadline=None)
@given(
    valid_goals(),
    st.sampled_from(
        [
            "nan_pos",
            "inf_pos",
            "limit",
            "wrap",
            "time_back",
            "too_long",
            "nan_tol",
            "inf_tol",
            "nan_gtt",
            "neg_gtt",
            "tol_other_joint",
            "fast",
            "margin",
            "accel",
            "last_velocity",
            "short_row",
            "neg_time",
        ]
    ),
)
def test_each_broken_rule_is_refused_with_its_code(case, fault):
    goal, current = case
    names, times = list(goal.joint_names), list(goal.times_s)
    rows = [list(r) for r in goal.positions]
    kw = dict(path_tolerance={}, goal_tolerance={}, goal_time_tolerance_s=0.0, velocities=None)
    code = ac.INVALID_GOAL
    n0 = names[0]
    lo, hi = m.JOINT_LIMITS[n0]
    if fault == "nan_pos":
        rows[-1][0] = math.nan
    elif fault == "inf_pos":
        rows[-1][0] = -math.inf
    elif fault == "limit":
        rows[-1][0] = hi + 0.01
    elif fault == "wrap":  # the same angle one turn on: not the same command on a bounded joint
        rows[-1][0] = rows[-1][0] + 2.0 * math.pi
    elif fault == "time_back":
        times = times + [times[-1]]
        rows = rows + [rows[-1]]
    elif fault == "too_long":
        times = [t + CONTRACT.max_trajectory_s for t in times]
    elif fault == "nan_tol":
        kw["path_tolerance"] = {n0: math.nan}
    elif fault == "inf_tol":
        kw["goal_tolerance"] = {n0: math.inf}
    elif fault == "nan_gtt":
        kw["goal_time_tolerance_s"] = math.nan
    elif fault == "neg_gtt":
        kw["goal_time_tolerance_s"] = -0.1
    elif fault == "tol_other_joint":
        kw["goal_tolerance"] = {"katana_bogus_joint": 0.1}
        code = ac.INVALID_JOINTS
    elif fault == "fast":  # the whole range in 10 ms
        rows[0][0] = hi if current[n0] - lo < hi - current[n0] else lo
        times = [0.01 + 0.01 * i for i in range(len(times))]
    elif fault == "margin":  # inside the joint limits, but within 200 encoders of one
        rows[-1][0] = hi - 0.5 * MARGIN_RAD[n0]
        times = [t + 1e3 for t in times]  # slow enough for any move
    elif fault == "accel":  # one move at twice the acceleration limit, well within the speed
        h = 0.4
        d = 2.0 * ACCEL[n0] * h * h / 6.0
        mid = 0.5 * (lo + hi)
        names, times = [n0], [h]
        rows = [[current[n0] + (d if current[n0] < mid else -d)]]
        assert 1.5 * d / h < m.JOINT_MAX_SPEED[n0]
    elif fault == "last_velocity":
        kw["velocities"] = [[0.0] * len(names) for _ in times]
        kw["velocities"][-1][0] = 0.1
    elif fault == "short_row":
        rows[0] = rows[0][:-1]
    elif fault == "neg_time":
        times[0] = -1e-3
    bad = ac.TrajectoryGoal(names, times, rows, **kw)
    verdict = ac.validate_trajectory(bad, current, CONTRACT)
    assert verdict.error_code == code, (fault, verdict)
    assert verdict.error_string
    if fault == "margin":
        assert "within 200 encoders" in verdict.error_string
    if fault == "accel":
        assert "acceleration" in verdict.error_string


@pytest.mark.parametrize(
    "names, code",
    [
        ([], ac.INVALID_JOINTS),
        (["katana_r_finger_joint"], ac.INVALID_JOINTS),
        (["katana_motor1_pan_joint", "katana_motor1_pan_joint"], ac.INVALID_JOINTS),
        (["bogus"], ac.INVALID_JOINTS),
    ],
)
def test_bad_joint_names(names, code):
    goal = ac.TrajectoryGoal(names, [2.0], [[0.0] * len(names)])
    assert ac.validate_trajectory(goal, REST, CONTRACT).error_code == code


def test_duplicate_tolerance_pairs_are_refused():
    n = m.ARM_JOINTS[0]
    goal = ac.TrajectoryGoal([n], [2.0], [[REST[n]]], goal_tolerance=[(n, 0.1), (n, 0.2)])
    assert ac.validate_trajectory(goal, REST, CONTRACT).error_code == ac.INVALID_JOINTS


def test_a_goal_beyond_max_trajectory_s_is_refused_at_once():
    n = m.ARM_JOINTS[0]
    goal = ac.TrajectoryGoal([n], [1e5], [[REST[n]]])
    verdict = ac.validate_trajectory(goal, REST, ac.ArmContract(max_trajectory_s=30.0))
    assert verdict.error_code == ac.INVALID_GOAL
    assert "max_trajectory_s" in verdict.error_string


_any_float = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10, 10))


@settings(max_examples=300, deadline=None)
@given(
    names=st.lists(st.one_of(st.sampled_from(m.ALL_JOINTS), st.text(max_size=5)), max_size=6),
    times=st.lists(_any_float, max_size=4),
    rows=st.lists(st.lists(_any_float, max_size=6), max_size=4),
    vels=st.one_of(st.none(), st.lists(st.lists(_any_float, max_size=6), max_size=4)),
    tol=st.dictionaries(st.sampled_from(m.ALL_JOINTS), _any_float, max_size=3),
    gtt=_any_float,
)
def test_arbitrary_goals_get_a_verdict_never_an_exception(names, times, rows, vels, tol, gtt):
    goal = ac.TrajectoryGoal(names, times, rows, vels, tol, tol, gtt)
    verdict = ac.validate_trajectory(goal, REST, CONTRACT)
    assert verdict.error_code in (ac.SUCCESSFUL, ac.INVALID_GOAL, ac.INVALID_JOINTS)
    assert verdict.ok == (verdict.error_string == "")
    if verdict.ok:  # then every number is finite and within the limits
        for row in rows:
            for n, q in zip(names, row, strict=True):
                assert m.JOINT_LIMITS[n][0] - 1e-6 <= q <= m.JOINT_LIMITS[n][1] + 1e-6


@settings(max_examples=200, deadline=None)
@given(
    p0=st.floats(-3, 3),
    p1=st.floats(-3, 3),
    v0=st.floats(-2, 2),
    v1=st.floats(-2, 2),
    h=st.floats(0.05, 5.0),
)
def test_hermite_peak_matches_dense_sampling(p0, p1, v0, v1, h):
    s = np.linspace(0.0, 1.0, 20001)
    # derivative of the cubic Hermite basis, independent of the closed form
    vel = (
        (6 * s**2 - 6 * s) * p0
        + (3 * s**2 - 4 * s + 1) * v0 * h
        + (-6 * s**2 + 6 * s) * p1
        + (3 * s**2 - 2 * s) * v1 * h
    ) / h
    sampled = float(np.max(np.abs(vel)))
    peak = ac.hermite_peak_speed(p0, p1, v0, v1, h)
    assert peak >= sampled - 1e-9
    assert peak <= sampled + 1e-3 * (1.0 + sampled)


@settings(max_examples=100, deadline=None)
@given(valid_goals(partial=False), st.floats(1e-3, 0.3))
def test_judge_succeeds_on_the_path_and_flags_a_deviation(case, deviation):
    goal, current = case
    n = goal.joint_names[0]
    goal = ac.TrajectoryGoal(
        goal.joint_names,
        goal.times_s,
        goal.positions,
        path_tolerance={n: deviation},
        goal_tolerance={},
    )
    final = list(goal.positions[-1])
    judge = ac.TrajectoryJudge(goal, CONTRACT)
    mid = 0.5 * goal.times_s[-1]
    desired = [current[x] for x in goal.joint_names]
    assert not judge.check(mid, desired, desired).done
    assert judge.check(goal.times_s[-1], final, final).status == ac.SUCCEEDED
    judge = ac.TrajectoryJudge(goal, CONTRACT)
    off = list(desired)
    off[0] += deviation * 1.01
    out = judge.check(mid, desired, off)
    assert (out.status, out.error_code) == (ac.ABORTED, ac.PATH_TOLERANCE_VIOLATED)
    assert n in out.message


def test_path_and_goal_tolerances_may_name_the_held_fingers_once():
    n = m.ARM_JOINTS[0]
    fingers = m.FINGER_JOINTS[0]
    for kind in ("path_tolerance", "goal_tolerance"):
        ok = ac.TrajectoryGoal([n], [2.0], [[REST[n]]], **{kind: {fingers: 0.05}})
        assert ac.validate_trajectory(ok, REST, CONTRACT).ok
        twice = ac.TrajectoryGoal([n], [2.0], [[REST[n]]],
                                  **{kind: [(fingers, 0.05), (fingers, 0.1)]})
        verdict = ac.validate_trajectory(twice, REST, CONTRACT)
        assert verdict.error_code == ac.INVALID_JOINTS and fingers in verdict.error_string
        other = ac.TrajectoryGoal([n], [2.0], [[REST[n]]], **{kind: {m.ARM_JOINTS[1]: 0.05}})
        verdict = ac.validate_trajectory(other, REST, CONTRACT)
        assert verdict.error_code == ac.INVALID_JOINTS and m.ARM_JOINTS[1] in verdict.error_string


FINGERS_START = 0.2  # rad: where the fingers are when a finger-tolerance goal starts


def _on_fingers(case, tol_r: float, tol_l: float, which: str, given_start: bool, kind: str):
    """`case`'s goal with finger tolerances (`kind`: path_tolerance or goal_tolerance) on the
    right, left or both fingers; its judge (the fingers' start given or not), the desired row at
    the start, and the tolerance that counts (the smallest given)."""
    goal, current = case
    tols = {"right": {m.FINGER_JOINTS[0]: tol_r}, "left": {m.FINGER_JOINTS[1]: tol_l},
            "both": {m.FINGER_JOINTS[0]: tol_r, m.FINGER_JOINTS[1]: tol_l}}[which]
    goal = ac.TrajectoryGoal(goal.joint_names, goal.times_s, goal.positions, **{kind: tols})
    judge = ac.TrajectoryJudge(goal, CONTRACT,
                               fingers_start=FINGERS_START if given_start else None)
    return goal, judge, [current[x] for x in goal.joint_names], min(tols.values())


def _moved(moved: float) -> float:
    """How far fingers moved by `moved` from FINGERS_START are, as floats give it (at the
    boundary too)."""
    return abs((FINGERS_START + moved) - FINGERS_START)


@settings(max_examples=200, deadline=None)
@given(valid_goals(partial=False), st.floats(1e-3, 0.3), st.floats(1e-3, 0.3),
       st.floats(-0.5, 0.5), st.sampled_from(["right", "left", "both"]),
       st.booleans(), st.floats(0.0, 1.5))
def test_the_fingers_held_by_a_trajectory_stop_it_when_they_move(
        case, tol_r, tol_l, moved, which, given_start, when):
    """A finger path tolerance stops the motion, while it runs, exactly when the fingers'
    angle is further than the smallest given tolerance from where they started (given, or the
    first angle judged); after the plan's end only the goal tolerances count."""
    goal, judge, desired, tolerance = _on_fingers(case, tol_r, tol_l, which, given_start,
                                                  "path_tolerance")
    start = FINGERS_START
    # on the path, or up to half the goal time after its end (the goal is not yet late)
    end = goal.times_s[-1]
    late_s = CONTRACT.default_goal_time_tolerance_s
    elapsed = when * end if when < 1.0 else end + (when - 1.0) * late_s
    if not given_start:  # the first angle judged is where they started
        assert not judge.check(0.0, desired, desired, at_rest=False, fingers=start).done
    out = judge.check(elapsed, desired, desired, at_rest=False, fingers=start + moved)
    stops = elapsed < goal.times_s[-1] and _moved(moved) > tolerance
    assert out.done == stops
    if stops:
        assert (out.status, out.error_code) == (ac.ABORTED, ac.PATH_TOLERANCE_VIOLATED)
        assert ac.fingers_moved(out.error_code, out.message)
    # without the fingers' angle, or without a tolerance on them, nothing is judged on them
    blind = ac.TrajectoryJudge(goal, CONTRACT, fingers_start=start)
    assert not blind.check(elapsed, desired, desired, at_rest=False).done
    free = ac.TrajectoryJudge(dataclasses.replace(goal, path_tolerance={}), CONTRACT, start)
    assert not free.check(elapsed, desired, desired, at_rest=False, fingers=start + moved).done


@settings(max_examples=200, deadline=None)
@given(valid_goals(partial=False), st.floats(1e-3, 0.3), st.floats(1e-3, 0.3),
       st.floats(-0.5, 0.5), st.sampled_from(["right", "left", "both"]), st.booleans(),
       st.floats(0.0, 0.99))
def test_the_fingers_are_judged_where_a_trajectory_ends_by_their_goal_tolerance(
        case, tol_r, tol_l, moved, which, given_start, when):
    """A finger goal tolerance fails the goal exactly when, at the end (the arm at rest within
    its goal tolerances), the fingers' angle is further than the smallest given tolerance from
    where they started; along the path it judges nothing."""
    goal, judge, desired, tolerance = _on_fingers(case, tol_r, tol_l, which, given_start,
                                                  "goal_tolerance")
    start = FINGERS_START
    final = [float(q) for q in goal.positions[-1]]
    end = goal.times_s[-1]
    if not given_start:  # the first angle judged is where they started
        assert not judge.check(0.0, desired, desired, at_rest=False, fingers=start).done
    # on the path (before the end) a finger goal tolerance judges nothing
    assert not judge.check(when * end, desired, desired, at_rest=False,
                           fingers=start + moved).done
    out = judge.check(end, final, final, at_rest=True, fingers=start + moved)
    assert out.done
    if _moved(moved) > tolerance:
        assert (out.status, out.error_code) == (ac.ABORTED, ac.GOAL_TOLERANCE_VIOLATED)
        assert ac.fingers_moved(out.error_code, out.message)
    else:
        assert out.status == ac.SUCCEEDED
    # without the fingers' angle nothing is judged on them
    blind = ac.TrajectoryJudge(goal, CONTRACT, fingers_start=start)
    assert blind.check(end, final, final, at_rest=True).status == ac.SUCCEEDED


def test_an_arm_tolerance_error_is_not_a_finger_failure():
    n = m.ARM_JOINTS[0]
    goal = ac.TrajectoryGoal([n], [2.0], [[REST[n]]], path_tolerance={n: 0.01})
    out = ac.TrajectoryJudge(goal, CONTRACT).check(1.0, [REST[n]], [REST[n] + 0.1])
    assert out.error_code == ac.PATH_TOLERANCE_VIOLATED
    assert not ac.fingers_moved(out.error_code, out.message)
    judge = ac.TrajectoryJudge(goal, CONTRACT, fingers_start=0.2)
    late = judge.check(2.0 + CONTRACT.default_goal_time_tolerance_s + 0.1, [REST[n]],
                       [REST[n] + 0.1], fingers=0.2)
    assert late.error_code == ac.GOAL_TOLERANCE_VIOLATED
    assert not ac.fingers_moved(late.error_code, late.message)


def test_judge_goal_tolerance_and_settle_time():
    names = list(m.ARM_JOINTS)
    final = [REST[n] for n in names]
    goal = ac.TrajectoryGoal(names, [2.0], [final], goal_time_tolerance_s=0.5)
    judge = ac.TrajectoryJudge(goal, CONTRACT)
    near = list(final)
    near[3] += 2 * CONTRACT.default_goal_tolerance_rad
    assert not judge.check(2.2, final, near).done  # still settling
    assert not judge.check(2.3, final, final, at_rest=False).done  # within but moving
    out = judge.check(2.51, final, near)
    assert (out.status, out.error_code) == (ac.ABORTED, ac.GOAL_TOLERANCE_VIOLATED)
    assert names[3] in out.message
    # negative tolerance: no goal tolerance for that joint
    goal = ac.TrajectoryGoal(names, [2.0], [final], goal_tolerance={names[3]: -1.0})
    assert ac.TrajectoryJudge(goal, CONTRACT).check(2.0, final, near).status == ac.SUCCEEDED


def test_errors_are_not_wrapped_on_bounded_joints():
    """Near the pan joint's ends, -3.0 and 2.8 are 5.8 rad apart, not 0.48."""
    n = m.ARM_JOINTS[0]
    goal = ac.TrajectoryGoal([n], [5.0], [[2.8]])
    judge = ac.TrajectoryJudge(goal, CONTRACT)
    out = judge.check(7.0, [2.8], [-3.0])
    assert out.error_code == ac.GOAL_TOLERANCE_VIOLATED
    assert "5.8000" in out.message


@settings(max_examples=200, deadline=None)
@given(pos=_any_float, effort=_any_float, arm=st.booleans())
def test_gripper_validation(pos, effort, arm):
    verdict = gc.validate_gripper(gc.GripperGoal(pos, effort), arm_active=arm)
    ok = (
        math.isfinite(pos)
        and m.GRIPPER_CLOSED - 1e-6 <= pos <= m.GRIPPER_OPEN + 1e-6
        and math.isfinite(effort)
        and effort >= 0
        and not arm
    )
    assert verdict.ok == ok
    assert verdict.error_code in (ac.SUCCESSFUL, ac.INVALID_GOAL)
    if arm and not ok:
        assert verdict.error_string


@settings(max_examples=100, deadline=None)
@given(
    start=st.floats(m.GRIPPER_CLOSED, m.GRIPPER_OPEN),
    goal=st.floats(m.GRIPPER_CLOSED, m.GRIPPER_OPEN),
    block_frac=st.floats(0.2, 0.8),
)
def test_gripper_judge_reaches_or_stalls(start, goal, block_frac):
    contract = ac.ArmContract()
    dt = 0.01
    speed = m.JOINT_MAX_SPEED["katana_r_finger_joint"]
    # Free fingers following the ideal ramp reach the goal.
    judge = gc.GripperJudge(gc.GripperGoal(goal), start, contract)
    t, out = 0.0, judge.outcome
    while not out.done:
        t += dt
        out = judge.check(t, judge.ideal(t), speed)
        assert t < judge.time_limit_s + 1.0
    assert out.reached_goal and out.status == ac.SUCCEEDED
    # Fingers stopped by a block part-way: stalled, not reached.
    if abs(goal - start) < 0.2:
        return
    stop = start + block_frac * (goal - start)
    judge = gc.GripperJudge(gc.GripperGoal(goal), start, contract)
    t, pos, out = 0.0, start, judge.outcome
    while not out.done:
        t += dt
        ideal = judge.ideal(t)
        moving = (ideal - stop) * (goal - start) < 0
        pos = ideal if moving else stop
        out = judge.check(t, pos, speed if moving else 0.0)
        assert t < judge.time_limit_s + 1.0
    assert out.stalled and not out.reached_goal and out.status == ac.SUCCEEDED
    assert abs(out.position - stop) < 1e-9


def test_contract_settings_are_checked():
    with pytest.raises(ValueError, match="max_trajectory_s"):
        ac.ArmContract(max_trajectory_s=math.inf)
    with pytest.raises(ValueError, match="6M90A"):
        ac.ArmContract(model="450_6m90a")


@pytest.mark.parametrize("joint", m.ARM_JOINTS)
def test_acceleration_limit_is_the_controllers(joint):
    """A rest-to-rest move just under 2 encoders per tick squared is accepted, just over it
    refused (6 d / h^2 at its ends); the limit is the driver's, from the same constants."""
    assert CONTRACT.max_accel[joint] == pytest.approx(ACCEL[joint], rel=1e-12)
    h = 0.5
    lo, hi = CONTRACT.target_limits[joint]
    start = dict(REST)
    for factor, ok in ((0.99, True), (1.01, False)):
        d = factor * ACCEL[joint] * h * h / 6.0
        goal = ac.TrajectoryGoal([joint], [h], [[REST[joint] + d]])
        assert ac.validate_trajectory(goal, start, CONTRACT).ok == ok, factor
    # a contract with another limit (a driver set to acceleration_limits 1) halves it
    slow = ac.ArmContract(acceleration_limits=(1.0,) * 5)
    assert slow.max_accel[joint] == pytest.approx(ACCEL[joint] / 2.0)


@pytest.mark.parametrize("joint", m.ARM_JOINTS)
def test_targets_keep_the_limit_margin_but_the_start_may_not(joint):
    """Targets 200 encoders inside the limits are accepted, closer ones refused; a point at
    t = 0 (where the arm is) may be anywhere within the limits, the arm may start there, and a
    joint held where it is is no new target."""
    lo, hi = m.JOINT_LIMITS[joint]
    assert CONTRACT.target_limits[joint] == pytest.approx(
        (lo + MARGIN_RAD[joint], hi - MARGIN_RAD[joint]), abs=1e-9)
    near = dict(REST, **{joint: hi - 0.1 * MARGIN_RAD[joint]})  # the arm inside the margin
    margin = MARGIN_RAD[joint]
    cases = ((hi - 1.01 * margin, True), (hi - 0.99 * margin, False), (near[joint], True))
    for target, ok in cases:
        goal = ac.TrajectoryGoal([joint], [0.0, 3.0], [[near[joint]], [target]])
        assert ac.validate_trajectory(goal, near, CONTRACT).ok == ok, target
    wide = ac.ArmContract(limit_margin_enc=0)
    goal = ac.TrajectoryGoal([joint], [3.0], [[hi]])
    assert ac.validate_trajectory(goal, near, wide).ok
    assert not ac.validate_trajectory(goal, near, CONTRACT).ok


def test_the_point_count_is_refused_past_its_limit_only() -> None:
    assert ac.check_point_count(0).ok and ac.check_point_count(ac.MAX_TRAJECTORY_POINTS).ok
    over = ac.check_point_count(ac.MAX_TRAJECTORY_POINTS + 1)
    assert over.error_code == ac.INVALID_GOAL
    assert f"{ac.MAX_TRAJECTORY_POINTS + 1} points" in over.error_string
