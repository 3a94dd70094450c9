"""The pick-and-place planner and sequence without physics: reach, limits, speeds, failures."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from katana_description import arm_contract as ac
from katana_description import models as m
from katana_manipulation.core import pick_place as pp
from katana_manipulation.core import planner as planner_module
from katana_manipulation.core.kinematics import MAX_SPEED, KatanaKinematics

KIN = KatanaKinematics()
LOWER = np.array([m.JOINT_LIMITS[j][0] for j in m.ARM_JOINTS])
UPPER = np.array([m.JOINT_LIMITS[j][1] for j in m.ARM_JOINTS])
TICKS_PER_REV = np.array([51200, 94976, 47488, 51200, 51200])
#: KNI's acceleration limit, 2 encoders per (10 ms)^2, in rad/s^2
ACCEL = 2.0 / (TICKS_PER_REV / (2 * math.pi)) / 0.01**2


def test_placement_reachable_agrees_with_the_full_plan():
    planner = pp.PickPlacePlanner()
    rng = np.random.default_rng(2)
    for _ in range(60):
        r, a = rng.uniform(0.1, 0.33), rng.uniform(-1.0, 1.0)
        place = (r * math.cos(a), r * math.sin(a), 0.015 + 0.03 * int(rng.integers(0, 4)))
        yaw = float(rng.uniform(-1, 1))
        ok, why = planner.placement_reachable(place, yaw)
        req = pp.PickPlaceRequest((0.2, 0.0, 0.015), 0.0, (0.04, 0.04, 0.03), place, yaw)
        try:
            planner.plan(req, m.PARK_POSE)
            planned = True
        except pp.PlanError as exc:
            planned = False
            assert exc.code == pp.PLACE_UNREACHABLE
        assert ok == planned, (place, why)
        assert ok or "unreachable" in why or "no room" in why


def test_plan_respects_limits_speeds_and_descends_vertically():
    planner = pp.PickPlacePlanner()
    req = pp.PickPlaceRequest((0.22, -0.08, 0.015), 0.4, (0.04, 0.04, 0.03),
                              (0.18, 0.1, 0.045), -0.7)
    segs = planner.plan(req, m.PARK_POSE)
    q_prev = np.array(m.PARK_POSE)
    for seg in (s for s in segs if s.kind == "arm"):
        t_prev, v_prev = 0.0, np.zeros(5)
        assert np.allclose(seg.velocities[-1], 0.0)  # every move ends at rest
        for q, t, v in zip(seg.points, seg.times, seg.velocities, strict=True):
            q, v = np.array(q), np.array(v)
            assert KIN.limit_violation(q) is None
            # 200 encoders inside the joint limits (docs/KATANA.md's ticks per revolution)
            inside = np.minimum(q - LOWER, UPPER - q) * TICKS_PER_REV / (2 * math.pi)
            assert np.all(inside >= 200.0)
            # the cubic Hermite segment's speed and acceleration, sampled densely (the latter
            # by finite differences), stay within the limits
            s = np.linspace(0.0, 1.0, 201)[:, None]
            h = t - t_prev
            assert round(h / 0.01) == pytest.approx(h / 0.01, abs=1e-6)  # whole 10 ms ticks
            vel = ((6 * s - 6 * s**2) * (q - q_prev) / h + (3 * s**2 - 4 * s + 1) * v_prev
                   + (3 * s**2 - 2 * s) * v)
            assert np.all(np.abs(vel) <= MAX_SPEED * planner.p.speed_fraction + 1e-6)
            acc = np.diff(vel, axis=0) / (h / 200)
            assert np.all(np.abs(acc) <= ACCEL * planner.p.accel_fraction * (1 + 1e-3))
            q_prev, t_prev, v_prev = q, t, v
        if seg.phase == "lower" or "descend" in seg.also:  # the last points go straight down
            n = planner.p.descend_points + 2
            xy = np.array([KIN.tool_position(q)[:2] for q in seg.points[-n:]])
            assert np.ptp(xy, axis=0).max() < 1e-6
    # the held block stays above a stack of three wherever the arm pans (the transit)
    carry = next(s for s in segs if s.kind == "arm" and "carry" in (s.phase, *s.also))
    def panning(seg):
        first, last = seg.points[0][0], seg.points[-1][0]
        return [q for q in seg.points if min(abs(q[0] - first), abs(q[0] - last)) > 0.05]

    assert panning(carry)
    for q in panning(carry):
        assert KIN.tool_position(q)[2] - 0.003 - 0.015 > 0.09 + 0.005
    # and the open pads clear a stack of four on the way to the park pose
    park = next(s for s in segs if s.kind == "arm" and "park" in (s.phase, *s.also))
    assert panning(park)
    for q in panning(park):
        assert KIN.tool_position(q)[2] - m.FINGER_PAD_LENGTH / 2 > 0.12


class FakePort:
    """A fake arm that records its calls: every move succeeds at once, the arm stays at the
    park pose, and the fingers are at `fingers` (each subclass's grip moves them)."""

    def __init__(self, fingers: float) -> None:
        self.fingers = fingers
        self.calls: list[str] = []
        self.watches: list[float | None] = []  # each move's finger tolerance
        self.ends: list[float | None] = []  # each move's finger goal tolerance
        self.joint_reads = 0

    def move(self, points, times, velocities=None, finger_tolerance=None,
             finger_goal_tolerance=None):
        self.calls.append("move")
        self.watches.append(finger_tolerance)
        self.ends.append(finger_goal_tolerance)
        return pp.MoveResult(True)

    def joint_positions(self):
        self.joint_reads += 1
        q = dict(zip(m.ARM_JOINTS, m.PARK_POSE, strict=True))
        q.update({n: self.fingers for n in m.FINGER_JOINTS})
        return q


class ScriptedPort(FakePort):
    """A fake arm whose fingers close by `closes` rad during the move carrying the block (the
    block slips out, or settles deeper in the grip), judged by the arm contract with the
    finger tolerances the move has: along the path halfway, then at its end."""

    def __init__(self, closes: float = 0.275) -> None:
        super().__init__(fingers=0.3)
        self.closes = closes

    def grip(self, position, effort):
        self.calls.append(f"grip {position:.2f}")
        self.fingers = -0.165 if position < -0.4 else position
        return pp.GripResult(True, self.fingers, position < -0.4, position >= -0.4)

    def move(self, points, times, velocities=None, finger_tolerance=None,
             finger_goal_tolerance=None):
        super().move(points, times, velocities, finger_tolerance, finger_goal_tolerance)
        if self.calls.count("move") != 2:  # the second move carries the block
            return pp.MoveResult(True)
        start = self.fingers
        self.fingers = start - self.closes

        def tolerance(value):
            return dict.fromkeys(m.FINGER_JOINTS, -1.0 if value is None else value)

        judge = ac.TrajectoryJudge(
            ac.TrajectoryGoal(m.ARM_JOINTS, times, points,
                              path_tolerance=tolerance(finger_tolerance),
                              goal_tolerance=tolerance(finger_goal_tolerance)),
            ac.ArmContract(), fingers_start=start)
        out = judge.check(times[-1] / 2, points[0], points[0], fingers=self.fingers)
        if not out.done:
            out = judge.check(times[-1], points[-1], points[-1], fingers=self.fingers)
        if out.status == ac.SUCCEEDED:
            return pp.MoveResult(True)
        return pp.MoveResult(False, out.message,
                             fingers_moved=ac.fingers_moved(out.error_code, out.message))


def test_a_slip_while_carrying_stops_the_arm_there():
    """Lift, carry and lower are one move, sent with the slip tolerance on the fingers (and
    only that move): the backend stops it where the fingers close on nothing, and the result
    is a slip, found in the move and not by the check after it."""
    port = ScriptedPort()
    req = pp.PickPlaceRequest((0.2, 0.0, 0.015), 0.0, (0.04, 0.04, 0.03), (0.2, 0.1, 0.015), 0.0)
    planner = pp.PickPlacePlanner()
    res = pp.execute_pick_place(req, port, planner)
    assert res.code == pp.BLOCK_SLIPPED and "slipped" in res.message, res.message
    assert res.phase == "lift" and "lift/carry/lower: the fingers moved" in res.message
    assert port.watches[:2] == [None, planner.p.carry_slip_tolerance]
    assert all(w is None for w in port.watches[2:])  # the recovery moves are not watched


@pytest.mark.parametrize("closes", [0.03, 0.07])
def test_the_grip_is_judged_where_the_carrying_move_ends(closes):
    """Fingers that close by less than the carrying watch, but by more than slip_tolerance,
    fail the move at its end (the contract's finger goal tolerance, judged by the backend on
    its own measurement): a slip, found before the release and with nothing read from
    joint_states. Fingers that close less are a grip that held: the block is placed."""
    planner = pp.PickPlacePlanner()
    assert planner.p.slip_tolerance < 0.07 < planner.p.carry_slip_tolerance
    port = ScriptedPort(closes)
    req = pp.PickPlaceRequest((0.2, 0.0, 0.015), 0.0, (0.04, 0.04, 0.03), (0.2, 0.1, 0.015), 0.0)
    res = pp.execute_pick_place(req, port, planner)
    assert port.ends[:2] == [None, planner.p.slip_tolerance]
    assert all(e is None for e in port.ends[2:])
    if closes > planner.p.slip_tolerance:
        assert res.code == pp.BLOCK_SLIPPED and res.phase == "lift", res.message
        assert "by the end of the motion" in res.message
        # the recovery opens the fingers wide and parks; the release never ran
        assert port.calls[4:] == [f"grip {m.GRIPPER_OPEN:.2f}", "move"]
        assert port.joint_reads == 2  # where the task starts, where the recovery parks from
    else:
        assert res.code == pp.SUCCESS, res.message
        assert port.calls[4] == port.calls[0]  # released at the approach's opening
        assert port.joint_reads == 1  # only where the task starts


def test_the_recovery_parks_from_where_the_failure_left_the_arm():
    """After a slip the recovery opens the fingers, then plans the park from joints that show
    them open (the port's `settled`), not from the joints it held when the gripper's result
    came, which may be from before the arm stopped."""

    class LaggingPort(ScriptedPort):
        """joint_states that lag: until `settled` has waited for them, the port shows the arm
        where it stood before its last move. The carrying move stops halfway (the slip)."""

        def __init__(self) -> None:
            super().__init__()
            self.pose = self.shown = list(m.PARK_POSE)
            self.reads: list[list[float]] = []

        def move(self, points, times, velocities=None, finger_tolerance=None,
                 finger_goal_tolerance=None):
            res = super().move(points, times, velocities, finger_tolerance,
                               finger_goal_tolerance)
            self.shown = self.pose
            self.pose = [float(v) for v in points[-1 if res.ok else len(points) // 2]]
            return res

        def settled(self):
            self.shown = self.pose
            return True

        def joint_positions(self):
            self.reads.append(self.shown)
            q = dict(zip(m.ARM_JOINTS, self.shown, strict=True))
            q.update({n: self.fingers for n in m.FINGER_JOINTS})
            return q

    port = LaggingPort()
    req = pp.PickPlaceRequest((0.2, 0.0, 0.015), 0.0, (0.04, 0.04, 0.03), (0.2, 0.1, 0.015), 0.0)
    stopped_at = []
    carry = port.move

    def move(*args, **kwargs):
        res = carry(*args, **kwargs)
        if not res.ok:
            stopped_at.append(port.pose)
        return res

    port.move = move
    res = pp.execute_pick_place(req, port, pp.PickPlacePlanner())
    assert res.code == pp.BLOCK_SLIPPED, res.message
    assert port.calls[4:] == [f"grip {m.GRIPPER_OPEN:.2f}", "move"]  # open, then park
    assert port.reads[-1] == stopped_at[0]  # the park was planned from where the slip stopped


def test_slip_and_unresponsive_arm_are_reported():
    port = ScriptedPort()
    req = pp.PickPlaceRequest((0.2, 0.0, 0.015), 0.0, (0.04, 0.04, 0.03), (0.2, 0.1, 0.015), 0.0)
    res = pp.execute_pick_place(req, port, pp.PickPlacePlanner())
    assert res.code == pp.BLOCK_SLIPPED and "slipped" in res.message

    class Dead(ScriptedPort):
        def move(self, points, times, velocities=None, finger_tolerance=None,
                 finger_goal_tolerance=None):
            return pp.MoveResult(False, "no result within 3.0 s", timed_out=True)

    res = pp.execute_pick_place(req, Dead(), pp.PickPlacePlanner())
    assert res.code == pp.TIMEOUT

    class NoState(ScriptedPort):
        def joint_positions(self):
            return None

    res = pp.execute_pick_place(req, NoState(), pp.PickPlacePlanner())
    assert res.code == pp.TIMEOUT and "joint_states" in res.message


class JammedRelease(FakePort):
    """A fake arm whose fingers stay on the block when asked to open after the grasp, for the
    first `jammed_opens` such goals (the sim's pads can wedge a block that rests on its support)."""

    BLOCK = m.finger_angle_for_opening(0.04)

    def __init__(self, jammed_opens: int) -> None:
        super().__init__(fingers=m.GRIPPER_OPEN)
        self.jammed_opens = jammed_opens

    def grip(self, position, effort):
        self.calls.append(f"grip {position:.3f}")
        closing = position < self.BLOCK
        if closing:
            self.fingers = self.BLOCK
        elif self.fingers == self.BLOCK and self.jammed_opens > 0:
            self.jammed_opens -= 1  # stalled where it was
        else:
            self.fingers = position
        stalled = self.fingers != position
        return pp.GripResult(True, self.fingers, stalled, not stalled)


#: a place whose column does not lean in, so the release opens by the pregrasp margin only
REQ = pp.PickPlaceRequest((0.2, 0.0, 0.015), 0.0, (0.04, 0.04, 0.03), (0.18, 0.1, 0.045), 0.0)


def test_a_release_that_leaves_the_block_held_stops_the_arm_where_it_is():
    port = JammedRelease(jammed_opens=2)
    res = pp.execute_pick_place(REQ, port, pp.PickPlacePlanner())
    assert res.code == pp.ARM_DID_NOT_REACH and res.phase == "release"
    assert "still held" in res.message
    # the release, one wide opening more, and nothing after: a retreat would drag the block
    assert port.calls[-2:] == [port.calls[-2], f"grip {m.GRIPPER_OPEN:.3f}"]
    assert port.calls[-3] == "move" and port.calls.count("move") == 2  # up to the lowering


def test_a_release_that_opens_on_the_second_try_goes_on():
    port = JammedRelease(jammed_opens=1)
    res = pp.execute_pick_place(REQ, port, pp.PickPlacePlanner())
    assert res.success, res.message
    assert f"grip {m.GRIPPER_OPEN:.3f}" in port.calls
    assert port.calls[-1] == "move"  # retreated and parked after the second opening
    clean = JammedRelease(jammed_opens=0)
    assert pp.execute_pick_place(REQ, clean, pp.PickPlacePlanner()).success
    assert f"grip {m.GRIPPER_OPEN:.3f}" not in clean.calls  # the release opened the first time


def test_timing_that_does_not_settle_stops_at_every_point(monkeypatch):
    """Should stretching the segments not settle, every point becomes a stop and each segment
    is timed on its own: still within both limits."""
    planner = pp.PickPlacePlanner()
    pts = [np.array(m.PARK_POSE) + [0.6 * k, -0.1 * k, 0.1 * k, -0.2 * k, 0.3 * k]
           for k in (1, 2, 3)]
    monkeypatch.setattr(planner_module, "STRETCH_STEPS", 0)
    points, times, vels = planner.timed(m.PARK_POSE, pts)
    assert np.all(np.array(vels) == 0.0)
    q = np.vstack([m.PARK_POSE, points])
    h = np.diff([0.0, *times])
    speed, accel = planner_module.hermite_peaks(q, np.zeros_like(q), h)
    d = np.abs(np.diff(q, axis=0))  # from rest to rest: 1.5 d / h and 6 d / h^2
    assert np.allclose(speed, 1.5 * d / h[:, None]) and np.allclose(accel, 6 * d / h[:, None]**2)
    assert np.all(speed <= MAX_SPEED * planner.p.speed_fraction + 1e-9)
    assert np.all(accel <= ACCEL * planner.p.accel_fraction + 1e-9)


class _SignallingPlanner(pp.PickPlacePlanner):
    """The planner, saying when `plan` has started; it plans only once a grip has started (or
    a bounded wait ran out), and records which."""

    def __init__(self) -> None:
        super().__init__()
        self.planning = threading.Event()
        self.gripping = threading.Event()
        self.waited_for_grip: list[bool] = []

    def plan(self, req, current):
        self.planning.set()
        self.waited_for_grip.append(self.gripping.wait(5.0))
        return super().plan(req, current)


class OverlapPort(JammedRelease):
    """Records, for each grip, whether the plan had started before the grip returned (it waits
    a bounded time for it to)."""

    def __init__(self, planner: _SignallingPlanner) -> None:
        super().__init__(jammed_opens=0)
        self.planner = planner
        self.planned_during: list[bool] = []

    def grip(self, position, effort):
        self.planner.gripping.set()
        self.planned_during.append(self.planner.planning.wait(5.0))
        return super().grip(position, effort)


def test_the_fingers_open_while_the_moves_are_planned():
    """The first grip (to the pregrasp opening) runs while `plan` runs, not after it; the plan
    and the port calls are those of planning first (the same segments, once each)."""
    planner = _SignallingPlanner()
    port = OverlapPort(planner)
    res = pp.execute_pick_place(REQ, port, planner)
    assert res.success, res.message
    assert port.planned_during[0] and planner.waited_for_grip == [True]
    segs = pp.PickPlacePlanner().plan(REQ, m.PARK_POSE)
    assert segs[0].kind == "grip" and segs[0].phase == "approach"
    assert f"grip {segs[0].position:.3f}" == port.calls[0]
    expected = ["move" if s.kind == "arm" else f"grip {s.position:.3f}"
                for s in segs if s.kind in ("arm", "grip")]
    assert port.calls == expected


class RememberingPort(JammedRelease):
    """Remembers where its last grip ended, as RosArmPort and the physics port do."""

    def __init__(self) -> None:
        super().__init__(jammed_opens=0)
        self.gripped: float | None = None

    def grip(self, position, effort):
        out = super().grip(position, effort)
        self.gripped = out.position
        return out


def test_fingers_left_at_the_opening_need_no_gripper_goal():
    """The release leaves the fingers at the pregrasp opening of a block of the same size, so
    the next pick-and-place sends no goal to open them; fingers found elsewhere (moved by
    someone else since) get one."""
    planner = pp.PickPlacePlanner()
    segs = planner.plan(REQ, m.PARK_POSE)
    opening = f"grip {segs[0].position:.3f}"
    port = RememberingPort()
    assert pp.execute_pick_place(REQ, port, planner).success
    assert port.calls[0] == opening and port.gripped == pytest.approx(segs[0].position)
    port.calls.clear()
    assert pp.execute_pick_place(REQ, port, planner).success
    assert port.calls[0] == "move" and port.calls.count(opening) == 1  # the release's only
    port.calls.clear()
    port.fingers = m.GRIPPER_OPEN  # the gripper moved behind the port's back
    assert pp.execute_pick_place(REQ, port, planner).success
    assert port.calls[0] == opening


def test_a_goal_out_of_reach_moves_nothing():
    port = JammedRelease(jammed_opens=0)
    far = pp.PickPlaceRequest((0.9, 0.0, 0.015), 0.0, (0.04, 0.04, 0.03), (0.2, 0.1, 0.015), 0.0)
    res = pp.execute_pick_place(far, port, pp.PickPlacePlanner())
    assert res.code == pp.PICK_UNREACHABLE and port.calls == []


_OFFSETS = st.lists(st.floats(-0.05, 0.05, allow_nan=False), min_size=6, max_size=6)


@given(offsets=_OFFSETS, commanded_known=st.booleans(), gripped_known=st.booleans())
def test_holds_where_sent_agrees_with_the_planning_start_and_the_fingers_check(
        offsets, commanded_known, gripped_known):
    """holds_where_sent is true exactly when planning_start takes the commanded pose and the
    fingers agree with the last grip within the hold tolerance (each checked here directly)."""
    commanded = [0.3, 1.2, -1.0, -0.5, 0.2]
    gripped = 0.1
    joints = {n: c + d for n, c, d in zip(m.ARM_JOINTS, commanded, offsets, strict=False)}
    for n in m.FINGER_JOINTS:
        joints[n] = gripped + offsets[5]
    held_arm = pp.planning_start([joints[n] for n in m.ARM_JOINTS], commanded) == commanded
    held_fingers = abs(joints[m.FINGER_JOINTS[0]] - gripped) <= pp.HOLD_TOLERANCE_RAD
    expected = ((held_arm or not commanded_known) and (held_fingers or not gripped_known))
    assert pp.holds_where_sent(joints, commanded if commanded_known else None,
                               gripped if gripped_known else None) == expected
