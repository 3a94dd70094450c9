"""The sim's free-space moves (katana_sim PhysicsSim, `kinematic_free_space`): the arm follows its
plan without physics steps while it, and the block it holds, keep clear of everything else.

Checked against their reference twin, the same motions stepped in physics throughout, and
against PyBullet's exact distances (the check itself reasons on bounding boxes). Cross-package
(the planner drives the sim through tests/physics_port.py), so it lives here."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pybullet as p
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from katana_description import models as m
from katana_manipulation.core import pick_place as pp
from katana_manipulation.core.kinematics import KatanaKinematics, Unreachable
from katana_manipulation.core.pick_place_types import SIM_MIN_SEGMENT_TIME_S, PickPlaceParams
from katana_sim.core import PhysicsSim, SimConfig, TrajectoryGoal
from katana_sim.core.physics import FREE_SPACE_MARGIN_M

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib
from physics_port import PhysicsPort  # noqa: E402

KINEMATICS = KatanaKinematics()
PLANNER = pp.PickPlacePlanner(params=PickPlaceParams(min_segment_time=SIM_MIN_SEGMENT_TIME_S))


@pytest.fixture(scope="module")
def twins():
    """The same world twice: free-space moves on (fast) and off (the reference)."""
    fast = PhysicsSim(SimConfig(seed=0))
    reference = PhysicsSim(SimConfig(seed=0, kinematic_free_space=False))
    yield fast, reference
    fast.close()
    reference.close()


def _stack_on_first_reachable(world, seed: int):
    """Reset to `seed` and pick-and-place the first block the planner can put on another."""
    truth = world.reset(seed)
    start = [world.joint_positions()[n] for n in m.ARM_JOINTS]
    for a in truth:
        for b in truth:
            if a.id == b.id:
                continue
            place = (b.position[0], b.position[1], b.position[2] + b.size[2])
            req = pp.PickPlaceRequest(a.position, a.yaw, a.size, place, b.yaw)
            try:
                PLANNER.plan(req, start)
            except pp.PlanError:
                continue
            steps = world._steps
            res = pp.execute_pick_place(req, PhysicsPort(world), PLANNER)
            world.settle(max_time=1.0, min_time=1.0)
            return res, a.id, world._steps - steps
    raise AssertionError(f"the scene of seed {seed} has no block the planner can stack")


@pytest.mark.parametrize("seed", [1, 2, 5])
def test_a_pick_and_place_ends_as_its_physics_twin_with_most_steps_free(twins, seed):
    fast, reference = twins
    kinematic_before = fast.kinematic_steps
    res_fast, moved, steps_fast = _stack_on_first_reachable(fast, seed)
    res_ref, moved_ref, steps_ref = _stack_on_first_reachable(reference, seed)
    assert moved == moved_ref and res_fast.success == res_ref.success, (res_fast, res_ref)
    assert res_fast.success, res_fast
    fast_truth = {b.id: b for b in fast.ground_truth()}
    ref_truth = {b.id: b for b in reference.ground_truth()}
    for bid, ref in ref_truth.items():
        got = fast_truth[bid]
        assert got.level == ref.level and got.support == ref.support, bid
        assert math.dist(got.position, ref.position) < 0.0015, (bid, got.position, ref.position)
        assert abs(math.remainder(got.yaw - ref.yaw, math.pi / 2)) < 0.02, bid
    arm_fast = [fast.joint_positions()[n] for n in m.ALL_JOINTS]
    arm_ref = [reference.joint_positions()[n] for n in m.ALL_JOINTS]
    assert np.allclose(arm_fast, arm_ref, atol=2e-3)
    # the same simulated time, most of it without physics
    assert abs(steps_fast - steps_ref) <= 0.05 * steps_ref
    assert fast.kinematic_steps - kinematic_before > 0.85 * steps_fast


def _counting(step, calls: list[int]):
    """`step` that also appends each call's step count to `calls`."""
    def counted(n: int = 1) -> None:
        calls.append(n)
        step(n)
    return counted


@pytest.mark.parametrize("seed", [1, 2, 5])
def test_free_chunks_taken_in_one_call_end_as_chunk_by_chunk(seed):
    """The lock-step takes the chunks the arm crosses without physics in one `step` call
    (PhysicsSim.free_run): the same pick-and-place stepped chunk by chunk makes the same steps
    and ends in the same state, bit for bit."""
    ends = []
    for whole in (True, False):
        world = PhysicsSim(SimConfig(seed=0))
        try:
            if not whole:
                world.free_run = lambda chunk: 0  # every chunk on its own, as run_motion did
            calls: list[int] = []
            world.step = _counting(world.step, calls)
            res, _, steps = _stack_on_first_reachable(world, seed)
            assert res.success, res
            ends.append((steps, world.physics_steps, world.kinematic_steps,
                         [world.block_pose(b)[0].tolist() for b in world.blocks],
                         world.joint_state()[0].tolist(), len(calls)))
        finally:
            world.close()
    (*whole_end, whole_calls), (*chunked_end, chunked_calls) = ends
    assert whole_end == chunked_end
    assert whole_calls < chunked_calls / 3  # the free stretches went in few calls


def _distance(world, body: int) -> float:
    """PyBullet's exact shortest distance from the moving arm links to `body` (capped at 1 m)."""
    links = world._probe_links
    found = [c[8] for c in p.getClosestPoints(world.arm, body, 1.0, physicsClientId=world._cid)
             if c[3] in links]
    return min(found, default=1.0)


OUT_OF_THE_WAY = [(0.45, 0.30), (0.45, -0.30), (-0.30, 0.35)]
#: where the arm contract lets a target lie (so that few drawn goals are refused)
TARGET_LIMITS = m.inner_limits(m.JOINT_LIMITS)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(goal=st.tuples(*(st.floats(lo, hi) for lo, hi in
                        (TARGET_LIMITS[n] for n in m.ARM_JOINTS))),
       along=st.floats(0.2, 0.8), offset=st.tuples(st.floats(-0.05, 0.05), st.floats(-0.05, 0.05)),
       tall=st.integers(1, 4), seed=st.integers(0, 1000))
def test_a_step_made_without_physics_never_comes_near_a_block_or_the_table(goal, along, offset,
                                                                           tall, seed):
    """A tower of `tall` blocks stands near where the hand passes, `along` the way from the
    park pose to `goal`; the arm sweeps there."""
    world = PhysicsSim(SimConfig(seed=seed))
    try:
        start = np.array([world.joint_positions()[n] for n in m.ARM_JOINTS])
        world.set_arm_positions(start + along * (np.asarray(goal) - start))
        passing = world.tool_pose()[0]
        world.set_arm_positions(start)
        xy = (passing[0] + offset[0], passing[1] + offset[1])
        assume(0.12 < math.hypot(*xy) < 0.6 and passing[2] > 0.0)
        h = world.cfg.block_size[2]
        ids = list(world.blocks)
        for level, bid in enumerate(ids[:tall]):
            world.set_block_pose(bid, (*xy, h * (level + 0.5)))
        for bid, spare in zip(ids[tall:], OUT_OF_THE_WAY, strict=False):
            world.set_block_pose(bid, (*spare, h / 2))
        world.settle()
        # a rest-to-rest cubic over T peaks at 1.5 d / T in speed and 6 d / T^2 in acceleration
        travel = np.abs(np.subtract(goal, start))
        speeds = np.array([m.JOINT_MAX_SPEED[n] for n in m.ARM_JOINTS])
        accels = np.array([m.JOINT_MAX_ACCEL[n] for n in m.ARM_JOINTS])
        seconds = 1.2 * float(np.max(np.maximum(1.5 * travel / speeds,
                                                np.sqrt(6.0 * travel / accels)))) + 0.1
        handle = world.start_trajectory(TrajectoryGoal(list(m.ARM_JOINTS), [seconds], [goal]))
        assume(not handle.outcome.done)  # refused by the arm contract
        nearest = math.inf
        while not handle.outcome.done and world.time < seconds + 3.0:
            before = world.kinematic_steps
            world.step(1)
            if world.kinematic_steps > before:  # this pose was reached without physics
                table = _distance(world, world.table)
                nearest = min(nearest, table, *(_distance(world, b)
                                                for b in world.blocks.values()))
        assert nearest >= FREE_SPACE_MARGIN_M / 2
    finally:
        world.close()


def _finger_motion(world, goal: float, limit_s: float = 5.0):
    """Run one gripper goal to its end, one step at a time; the poses reached without physics
    and the outcome."""
    handle = world.start_gripper(goal)
    free_poses = 0
    nearest = math.inf
    end = world.time + limit_s
    while not handle.outcome.done and world.time < end:
        before = world.kinematic_steps
        world.step(1)
        if world.kinematic_steps > before:
            free_poses += 1
            nearest = min(nearest, _distance(world, world.table),
                          *(_distance(world, b) for b in world.blocks.values()))
    return handle.outcome, free_poses, nearest


@pytest.mark.parametrize("seed", [0, 3])
def test_an_empty_hand_clear_of_the_blocks_opens_and_closes_without_moving_them(seed):
    """At the park pose the fingers open and close as their physics twin's do, in the same
    simulated time, and not one block moves by a single bit (no physics step is made); the twin
    stepped in physics lets the blocks it has just settled creep."""
    fast = PhysicsSim(SimConfig(seed=seed))
    reference = PhysicsSim(SimConfig(seed=seed, kinematic_free_space=False))
    try:
        for world in (fast, reference):
            world.reset(seed)
            world.settle_motion()
        before = {b: fast.block_pose(b) for b in fast.blocks}
        physics_before = fast.physics_steps
        for goal in (m.GRIPPER_OPEN, m.GRIPPER_CLOSED, 0.0):
            t_fast, t_ref = fast.time, reference.time
            got, free_poses, nearest = _finger_motion(fast, goal)
            want, _, _ = _finger_motion(reference, goal)
            assert got.status == want.status == "succeeded", (got, want)
            assert got.reached_goal and not got.stalled, got
            assert abs(got.position - want.position) < 0.02
            assert abs((fast.time - t_fast) - (reference.time - t_ref)) < 0.1
            assert free_poses > 0 and nearest >= FREE_SPACE_MARGIN_M
        assert fast.physics_steps == physics_before
        for bid, (pos, quat) in before.items():
            now_pos, now_quat = fast.block_pose(bid)
            assert np.array_equal(pos, now_pos) and np.array_equal(quat, now_quat), bid
    finally:
        fast.close()
        reference.close()


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(offset=st.tuples(st.floats(-0.06, 0.06), st.floats(-0.06, 0.06)),
       above=st.floats(0.0, 0.1), goal=st.floats(m.GRIPPER_CLOSED, m.GRIPPER_OPEN),
       start=st.floats(m.GRIPPER_CLOSED, m.GRIPPER_OPEN), seed=st.integers(0, 1000))
def test_fingers_moved_without_physics_never_come_near_a_block(offset, above, goal, start, seed):
    """A block stands beside, under or between the fingers of a hand pointing down over the
    table; whatever the fingers do without physics keeps half the margin from it (PyBullet's
    exact distances), and a motion that would come nearer is stepped in physics."""
    world = PhysicsSim(SimConfig(seed=seed))
    try:
        over = np.array([0.22, 0.0, 0.0])
        try:
            solution = KINEMATICS.ik_top_down(over[0], over[1], 0.01 + above, 0.0)
        except Unreachable:
            assume(False)
        world.set_arm_positions(solution, fingers=start)
        h = world.cfg.block_size[2]
        ids = list(world.blocks)
        world.set_block_pose(ids[0], (over[0] + offset[0], over[1] + offset[1], h / 2))
        for bid, spare in zip(ids[1:], OUT_OF_THE_WAY, strict=False):
            world.set_block_pose(bid, (*spare, h / 2))
        world.settle()
        outcome, _, nearest = _finger_motion(world, goal)
        assert outcome.done
        assert nearest >= FREE_SPACE_MARGIN_M / 2
    finally:
        world.close()
