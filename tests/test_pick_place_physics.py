"""Pick-and-place on the PyBullet physics (no ROS): katana_manipulation's planner and sequence
driving katana_sim's PhysicsSim through tests/physics_port.py (both packages are needed: a
cross-package test, so it lives here)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from katana_description import models as m
from katana_manipulation.core import pick_place as pp
from katana_manipulation.core.kinematics import KatanaKinematics
from katana_sim.core import PhysicsSim, SimConfig

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib
from physics_port import PhysicsPort  # noqa: E402

KIN = KatanaKinematics()


@pytest.fixture(scope="module")
def world():
    w = PhysicsSim(SimConfig(seed=3))
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
    res = pp.execute_pick_place(_request(gt["red"], gt["blue"]), PhysicsPort(world),
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
    # parked out of the camera's view with the gripper open (at least as wide as the release)
    assert np.allclose(_arm(world), m.PARK_POSE, atol=0.01)
    assert world.joint_positions()["katana_r_finger_joint"] > 0.0


def test_third_block_makes_a_stack_of_three(world):
    gt = {b.id: b for b in world.reset(3)}
    port, planner = PhysicsPort(world), pp.PickPlacePlanner()
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
    res = pp.execute_pick_place(_request(gt["red"], blue, dx, dy), PhysicsPort(world),
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
    res = pp.execute_pick_place(far, PhysicsPort(world), pp.PickPlacePlanner())
    assert res.code == pp.PLACE_UNREACHABLE and "unreachable" in res.message
    assert "place" in res.message  # the old text, for readers of the message
    nan = pp.PickPlaceRequest((math.nan, 0.0, 0.015), 0.0, gt["red"].size, (0.2, 0, 0.015), 0.0)
    res = pp.execute_pick_place(nan, PhysicsPort(world), pp.PickPlacePlanner())
    assert res.code == pp.INVALID_GOAL and "non-finite" in res.message
    wide = pp.PickPlaceRequest(gt["red"].position, 0.0, (0.1, 0.1, 0.03), (0.2, 0, 0.015), 0.0)
    res = pp.execute_pick_place(wide, PhysicsPort(world), pp.PickPlacePlanner())
    assert res.code == pp.INVALID_GOAL and "wider than the gripper" in res.message
    assert np.allclose(_arm(world), before, atol=1e-3)


def test_grasp_at_an_empty_place_is_reported_missed(world):
    world.reset(3)
    req = pp.PickPlaceRequest((0.16, 0.09, 0.015), 0.0, (0.04, 0.04, 0.03), (0.25, 0.0, 0.015),
                              0.0)
    truth = {b.id: b.position for b in world.ground_truth()}
    assert all(np.hypot(x - 0.16, y - 0.09) > 0.06 for x, y, _ in truth.values())
    res = pp.execute_pick_place(req, PhysicsPort(world), pp.PickPlacePlanner())
    assert res.code == pp.GRASP_MISSED and res.phase == "grasp"
    assert np.allclose(_arm(world), m.PARK_POSE, atol=0.01)  # recovered to the park pose


def test_every_scattered_block_can_be_picked(world):
    """reset_world's scatter is within reach: a pick of each block plans from the park pose."""
    planner = pp.PickPlacePlanner()
    for seed in range(30):
        for b in world.reset(seed):
            req = pp.PickPlaceRequest(b.position, b.yaw, b.size, b.position, b.yaw)
            assert planner.plan(req, m.PARK_POSE), (seed, b.id)


