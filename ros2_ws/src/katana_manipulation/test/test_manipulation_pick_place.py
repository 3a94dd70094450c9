"""Pick-and-place on the PyBullet world (no ROS), and the sequence's failure handling."""

from __future__ import annotations

import math

import numpy as np
import pytest
from katana_description import models as m
from katana_manipulation.core import pick_place as pp
from katana_manipulation.core.kinematics import MAX_SPEED, KatanaKinematics
from katana_manipulation.core.sim_port import WorldPort
from katana_sim.core import SimConfig, SimWorld

KIN = KatanaKinematics()


@pytest.fixture(scope="module")
def world():
    w = SimWorld(SimConfig(seed=3))
    yield w
    w.close()


def _request(a, b, dx=0.0, dy=0.0, levels=1) -> pp.PickPlaceRequest:
    h = a.size[2]
    place = (b.position[0] + dx, b.position[1] + dy, b.position[2] + h * levels)
    return pp.PickPlaceRequest(a.position, a.yaw, a.size, place, b.yaw)


def _arm(world) -> np.ndarray:
    q = world.joint_positions()
    return np.array([q[n] for n in m.ARM_JOINTS])


def test_pick_and_place_stacks_one_block_on_another(world):
    gt = {b.id: b for b in world.reset(3)}
    phases = []
    res = pp.execute_pick_place(_request(gt["red"], gt["blue"]), WorldPort(world),
                                pp.PickPlacePlanner(), lambda ph, pr: phases.append(ph))
    assert res.success, res
    world.settle()
    truth = {b.id: b for b in world.ground_truth()}
    assert truth["red"].level == 2 and truth["red"].support == "blue"
    assert np.hypot(*(np.array(truth["red"].position[:2]) - gt["blue"].position[:2])) < 0.004
    # square block: the placed yaw equals the wanted one modulo 90 degrees
    d = truth["red"].yaw - gt["blue"].yaw
    assert abs(math.remainder(d, math.pi / 2)) < 0.03
    assert [ph for i, ph in enumerate(phases) if i == 0 or phases[i - 1] != ph] == list(pp.PHASES)
    # parked out of the camera's view with the gripper open
    assert np.allclose(_arm(world), m.PARK_POSE, atol=0.01)
    assert world.joint_positions()["katana_r_finger_joint"] > 0.28


def test_third_block_makes_a_stack_of_three(world):
    gt = {b.id: b for b in world.reset(3)}
    port, planner = WorldPort(world), pp.PickPlacePlanner()
    assert pp.execute_pick_place(_request(gt["red"], gt["blue"]), port, planner).success
    assert pp.execute_pick_place(_request(gt["green"], gt["blue"], levels=2), port,
                                 planner).success
    world.settle()
    truth = {b.id: b for b in world.ground_truth()}
    assert truth["green"].level == 3 and truth["green"].on_top


def test_offset_placement_falls(world):
    gt = {b.id: b for b in world.reset(3)}
    blue = gt["blue"]
    # 75 % of the block beyond the support's edge, along the support's x axis
    dx, dy = 0.03 * math.cos(blue.yaw), 0.03 * math.sin(blue.yaw)
    res = pp.execute_pick_place(_request(gt["red"], blue, dx, dy), WorldPort(world),
                                pp.PickPlacePlanner())
    assert res.success, res  # the arm did its job; physics decides the outcome
    world.settle()
    truth = {b.id: b for b in world.ground_truth()}
    assert truth["red"].level == 1
    assert truth["blue"].on_top


def test_unreachable_and_invalid_goals_move_nothing(world):
    gt = {b.id: b for b in world.reset(3)}
    before = _arm(world)
    far = pp.PickPlaceRequest(gt["red"].position, 0.0, gt["red"].size, (0.45, 0.0, 0.015), 0.0)
    res = pp.execute_pick_place(far, WorldPort(world), pp.PickPlacePlanner())
    assert res.code == pp.UNREACHABLE and "unreachable" in res.message
    nan = pp.PickPlaceRequest((math.nan, 0.0, 0.015), 0.0, gt["red"].size, (0.2, 0, 0.015), 0.0)
    res = pp.execute_pick_place(nan, WorldPort(world), pp.PickPlacePlanner())
    assert res.code == pp.INVALID_GOAL and "non-finite" in res.message
    wide = pp.PickPlaceRequest(gt["red"].position, 0.0, (0.1, 0.1, 0.03), (0.2, 0, 0.015), 0.0)
    res = pp.execute_pick_place(wide, WorldPort(world), pp.PickPlacePlanner())
    assert res.code == pp.INVALID_GOAL and "wider than the gripper" in res.message
    assert np.allclose(_arm(world), before, atol=1e-3)


def test_grasp_at_an_empty_place_is_reported_missed(world):
    world.reset(3)
    req = pp.PickPlaceRequest((0.16, 0.09, 0.015), 0.0, (0.04, 0.04, 0.03), (0.25, 0.0, 0.015),
                              0.0)
    truth = {b.id: b.position for b in world.ground_truth()}
    assert all(np.hypot(x - 0.16, y - 0.09) > 0.06 for x, y, _ in truth.values())
    res = pp.execute_pick_place(req, WorldPort(world), pp.PickPlacePlanner())
    assert res.code == pp.GRASP_MISSED and res.phase == "grasp"
    assert np.allclose(_arm(world), m.PARK_POSE, atol=0.01)  # recovered to the park pose


def test_every_scattered_block_can_be_picked(world):
    """reset_world's scatter is within reach: a pick of each block plans from the park pose."""
    planner = pp.PickPlacePlanner()
    for seed in range(30):
        for b in world.reset(seed):
            req = pp.PickPlaceRequest(b.position, b.yaw, b.size, b.position, b.yaw)
            assert planner.plan(req, m.PARK_POSE), (seed, b.id)


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
            assert exc.code == pp.UNREACHABLE
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
            # the cubic Hermite segment's speed, sampled densely, stays within the limits
            s = np.linspace(0.0, 1.0, 201)[:, None]
            h = t - t_prev
            vel = ((6 * s - 6 * s**2) * (q - q_prev) / h + (3 * s**2 - 4 * s + 1) * v_prev
                   + (3 * s**2 - 2 * s) * v)
            assert np.all(np.abs(vel) <= MAX_SPEED * planner.p.speed_fraction + 1e-6)
            q_prev, t_prev, v_prev = q, t, v
        if seg.phase in ("descend", "lower"):
            xy = np.array([KIN.tool_position(q)[:2] for q in seg.points])
            assert np.ptp(xy, axis=0).max() < 1e-6
    # the held block stays above a stack of three while panning (transit height)
    carry = next(s for s in segs if s.phase == "carry")
    for q in carry.points[:2]:
        assert KIN.tool_position(q)[2] - 0.003 - 0.015 > 0.09


class ScriptedPort:
    """A fake arm whose fingers close further after the grasp: the block slipped."""

    def __init__(self) -> None:
        self.fingers = 0.3
        self.calls: list[str] = []

    def move(self, points, times, velocities=None):
        self.calls.append("move")
        return pp.MoveResult(True)

    def grip(self, position, effort):
        self.calls.append(f"grip {position:.2f}")
        self.fingers = -0.165 if position < -0.4 else position
        return pp.GripResult(True, self.fingers, position < -0.4, position >= -0.4)

    def joint_positions(self):
        if self.calls.count("move") >= 3:  # during the carry: fingers closed on nothing
            self.fingers = -0.44
        q = dict(zip(m.ARM_JOINTS, m.PARK_POSE, strict=True))
        q.update({n: self.fingers for n in m.FINGER_JOINTS})
        return q


def test_slip_and_unresponsive_arm_are_reported():
    port = ScriptedPort()
    req = pp.PickPlaceRequest((0.2, 0.0, 0.015), 0.0, (0.04, 0.04, 0.03), (0.2, 0.1, 0.015), 0.0)
    res = pp.execute_pick_place(req, port, pp.PickPlacePlanner())
    assert res.code == pp.BLOCK_SLIPPED and "slipped" in res.message

    class Dead(ScriptedPort):
        def move(self, points, times, velocities=None):
            return pp.MoveResult(False, "no result within 3.0 s", timed_out=True)

    res = pp.execute_pick_place(req, Dead(), pp.PickPlacePlanner())
    assert res.code == pp.TIMEOUT

    class NoState(ScriptedPort):
        def joint_positions(self):
            return None

    res = pp.execute_pick_place(req, NoState(), pp.PickPlacePlanner())
    assert res.code == pp.TIMEOUT and "joint_states" in res.message
