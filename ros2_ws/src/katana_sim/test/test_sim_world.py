"""The ROS-free PyBullet world: rendering, scatter, stability from physics, motors, validation."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pybullet as p
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_description import arm_contract as ac
from katana_description import models as m
from katana_sim.core import CameraModel, ConfigError, PhysicsSim, SimConfig, TrajectoryGoal
from katana_sim.core import controllers as ctl
from katana_sim.core.physics import FIRST_REACHING_LINK
from scipy.interpolate import CubicHermiteSpline


@pytest.fixture(scope="module")
def world():
    w = PhysicsSim(SimConfig(num_blocks=4, seed=1))
    yield w
    w.close()


def _colour_centroids(img: np.ndarray) -> dict[str, tuple[float, float, int]]:
    """Centroid (u, v) and pixel count of each block colour, by nearest table colour in RGB
    (an independent check of where the renderer drew each block)."""
    out = {}
    for name in m.DEFAULT_COLOURS:
        rgb = np.array(m.COLOURS[name][:3]) * 255
        # shading scales the colour: compare normalised chromaticity and require saturation
        pix = img.reshape(-1, 3).astype(float)
        norm = pix / np.maximum(pix.sum(axis=1, keepdims=True), 1)
        ref = rgb / rgb.sum()
        sat = pix.max(axis=1) - pix.min(axis=1)
        mask = (np.abs(norm - ref).sum(axis=1) < 0.08) & (sat > 60)
        mask = mask.reshape(img.shape[:2]).astype(np.uint8)
        n, labels, stats, cents = cv2.connectedComponentsWithStats(mask)
        if n > 1:
            k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
            out[name] = (cents[k][0], cents[k][1], int(stats[k, cv2.CC_STAT_AREA]))
    return out


def test_render_is_640x480_rgb_and_blocks_appear_where_ground_truth_says(world):
    for seed in (3, 11, 29):
        world.reset(seed)
        img = world.render()
        assert img.shape == (480, 640, 3) and img.dtype == np.uint8
        found = _colour_centroids(img)
        for b in world.ground_truth():
            assert b.visible
            u, v, area = found[b.id]
            # top face plus a sliver of the side faces: within 3 px of the projected top centre
            assert math.hypot(u - b.pixel_u, v - b.pixel_v) < 3.0, (b.id, u, v, b.pixel_u)
            # a 40 x 40 mm top at 0.72 m with f = 750 px is about 41.7 px on a side
            assert 1500 < area < 2300, (b.id, area)


def test_camera_model_matches_rendering_off_centre():
    cam = CameraModel(position=(0.25, 0.05, 0.6), rpy=(math.pi, 0.1, -math.pi / 2 + 0.3),
                      focal_px=600.0)
    w = PhysicsSim(SimConfig(num_blocks=1, camera=cam))
    try:
        w.set_block_pose("red", (0.3, 0.08, 0.015), 0.2)
        w.step(10)
        b = w.ground_truth()[0]
        u, v, _ = _colour_centroids(w.render())["red"]
        assert math.hypot(u - b.pixel_u, v - b.pixel_v) < 3.0
        # pixel_to_plane inverts project
        xyz = cam.pixel_to_plane(b.pixel_u, b.pixel_v, 0.03)
        assert np.allclose(xyz[:2], b.position[:2], atol=1e-6)
    finally:
        w.close()


def test_reset_scatters_valid_visible_and_seeded(world):
    """(That every scattered block can be picked is checked with the kinematics in
    katana_manipulation's tests.)"""
    cfg = world.cfg
    diag = math.hypot(*cfg.block_size[:2])
    for seed in range(40):
        blocks = world.reset(seed)
        pos = np.array([b.position for b in blocks])
        for b in blocks:
            x, y, z = b.position
            assert b.level == 1 and b.on_top and b.visible and not b.tilted
            assert abs(z - cfg.block_size[2] / 2) < 1e-3
            assert cfg.play_radius[0] <= math.hypot(x, y) <= cfg.play_radius[1]
            assert 0 <= b.pixel_u < 640 and 0 <= b.pixel_v < 480
        d = np.linalg.norm(pos[:, None, :2] - pos[None, :, :2], axis=2) + np.eye(len(pos))
        assert d.min() >= diag + cfg.min_gap - 1e-9
    a = [b.position for b in world.reset(5)]
    b = [b.position for b in world.reset(5)]
    assert np.allclose(a, b)


def test_eight_blocks_scatter():
    w = PhysicsSim(SimConfig(num_blocks=8, seed=4))
    try:
        blocks = w.ground_truth()
        assert len(blocks) == 8 and len({b.color for b in blocks}) == 8
        assert all(b.visible and b.level == 1 for b in blocks)
    finally:
        w.close()


def test_square_stack_stays_and_offset_block_falls(world):
    world.reset(2)
    # squarely on top: stays, level 2, in place
    world.stack("green", on="red", dx=0.0, dy=0.0)
    before = world.block_pose("green")[0]
    assert world.settle(max_time=3.0)
    world.step(int(1.0 / world.dt))
    truth = {b.id: b for b in world.ground_truth()}
    assert truth["green"].level == 2 and truth["green"].support == "red"
    assert not truth["red"].on_top and not truth["red"].visible
    assert np.linalg.norm(world.block_pose("green")[0] - before) < 2e-3
    # 70 % of its footprint over the edge: its centre of mass is unsupported, so it falls
    world.reset(2)
    world.stack("green", on="red", dx=0.028, dy=0.0, yaw=world.ground_truth()[0].yaw)
    world.settle(max_time=3.0)
    truth = {b.id: b for b in world.ground_truth()}
    assert truth["green"].level == 1
    assert truth["red"].on_top


def test_trajectory_reaches_target_within_tolerance_and_speed_limits(world):
    world.reset(0)
    # top-down at (0.2, 0.05, 0.09), yaw 0.3 (KatanaKinematics.ik_top_down)
    target = np.array([0.244979, 1.20566, -1.106029, 1.670427, 0.055021])
    start = np.array([world.joint_positions()[n] for n in m.ARM_JOINTS])
    d = np.abs(target - start)
    # two cubics from rest to rest, each over half the way in 0.6 dur: they peak at 1.5 times
    # their mean speed and accelerate at 6 (d / 2) / (0.6 dur)^2 at their ends
    dur = max(1.5 * float(np.max(d / kin_speed())),
              float(np.max(np.sqrt(3.0 * d / kin_accel()))) / 0.6)
    h = world.start_trajectory(TrajectoryGoal(list(m.ARM_JOINTS), [dur * 0.6, dur * 1.2],
                                              [list((start + target) / 2), list(target)]))
    vmax = np.zeros(5)
    while not h.outcome.done:
        world.step(4)
        _, vel, _ = world.joint_state()
        vmax = np.maximum(vmax, np.abs(vel[:5]))
    assert h.outcome.status == ac.SUCCEEDED, h.outcome
    q = np.array([world.joint_positions()[n] for n in m.ARM_JOINTS])
    assert np.all(np.abs(q - target) <= 0.005)
    assert np.all(vmax <= kin_speed() * 1.05), (vmax, kin_speed())
    assert np.linalg.norm(world.tool_pose()[0] - [0.2, 0.05, 0.09]) < 0.002


def kin_speed() -> np.ndarray:
    return np.array([m.JOINT_MAX_SPEED[n] for n in m.ARM_JOINTS])


def kin_accel() -> np.ndarray:
    """KNI's acceleration limit, 2 encoders per (10 ms)^2, in rad/s^2 (docs/KATANA.md's
    encoder ticks per revolution)."""
    return 2.0 / (np.array([51200, 94976, 47488, 51200, 51200]) / (2.0 * math.pi)) / 0.01**2


@pytest.mark.parametrize(
    ("names", "points", "times", "code", "why"),
    [
        (["katana_motor1_pan_joint"], [[math.nan]], [1.0], ac.INVALID_GOAL, "not finite"),
        (["bogus_joint"], [[0.0]], [1.0], ac.INVALID_JOINTS, "unknown"),
        (["katana_r_finger_joint"], [[0.0]], [1.0], ac.INVALID_JOINTS, "non-arm"),
        (["katana_motor2_lift_joint"], [[3.0]], [5.0], ac.INVALID_GOAL, "outside"),
        (["katana_motor1_pan_joint"], [[2.5]], [0.5], ac.INVALID_GOAL, "rad/s"),
        # inside the joint limit (2.891097), but within 200 encoders of it, as the arm refuses
        (["katana_motor1_pan_joint"], [[2.88]], [10.0], ac.INVALID_GOAL, "within 200 encoders"),
        # 0.4 rad of motor 2 from the park pose in 0.9 s: under its speed limit, but 2.96
        # rad/s^2 at the ends, above its 1.32 (2 encoders per (10 ms)^2)
        (["katana_motor2_lift_joint"], [[m.PARK_POSE[1] - 0.4]], [0.9], ac.INVALID_GOAL,
         "acceleration limit"),
        (["katana_motor1_pan_joint"], [[0.0], [0.1]], [2.0, 1.0], ac.INVALID_GOAL, "later than"),
    ],
)
def test_bad_trajectories_are_refused_with_a_reason(world, names, points, times, code, why):
    world.reset(0)
    h = world.start_trajectory(TrajectoryGoal(names, times, points))
    assert h.outcome.done and h.outcome.error_code == code and why in h.outcome.message
    assert not world.busy


#: the tool top-down at (0.2, 0, 0.018), where the red block is grasped; 6 cm higher
GRASP_Q = [0.0, 1.177257, -1.593299, 1.154754, 0.0]
ABOVE_Q = [0.0, 1.243947, -1.24856, 1.566184, 0.0]


def _grasp_red(world):
    """The red block on the table under the open hand at GRASP_Q, the fingers closed on it:
    the gripper goal's outcome."""
    world.reset(0)
    world.set_block_pose("red", (0.2, 0.0, 0.015), 0.0)
    world.set_arm_positions(GRASP_Q, 0.0)
    world.step(20)
    h = world.start_gripper(m.GRIPPER_CLOSED)
    while not h.outcome.done:
        world.step(6)
    return h.outcome


def test_gripper_holds_a_block_by_friction_only(world):
    grasp = _grasp_red(world)
    assert grasp.stalled and not grasp.reached_goal
    assert abs(grasp.position - m.finger_angle_for_opening(0.04)) < 0.02
    # the only constraint in the world is the gear coupling the two fingers
    n = p.getNumConstraints(physicsClientId=world._cid)
    assert n == 1
    info = p.getConstraintInfo(p.getConstraintUniqueId(0, physicsClientId=world._cid),
                               physicsClientId=world._cid)
    assert info[0] == info[2] == world.arm and info[4] == p.JOINT_GEAR
    h = world.start_trajectory(TrajectoryGoal(list(m.ARM_JOINTS), [1.2], [ABOVE_Q]))
    while not h.outcome.done:
        world.step(6)
    z = world.block_pose("red")[0][2]
    assert z > 0.015 + 0.05, z  # lifted with the hand
    # open: it drops back onto the table
    h = world.start_gripper(m.GRIPPER_OPEN)
    while not h.outcome.done:
        world.step(6)
    world.settle()
    assert abs(world.block_pose("red")[0][2] - 0.015) < 2e-3


@pytest.mark.parametrize("watch", [None, "path", "goal"])
def test_a_block_slipping_out_stops_a_trajectory_that_watches_the_fingers(world, watch):
    """A lift with the block taken out of the closed fingers (a slip): with a path tolerance on
    the fingers the arm stops where they closed past it, near where it started; with a goal
    tolerance on them it lifts the empty hand all the way and the goal fails there; without
    either it lifts the empty hand all the way, the slip unseen."""
    held = _grasp_red(world).position
    on_fingers = dict.fromkeys(m.FINGER_JOINTS, 0.05)
    h = world.start_trajectory(TrajectoryGoal(
        list(m.ARM_JOINTS), [1.2], [ABOVE_Q],
        path_tolerance=on_fingers if watch == "path" else {},
        goal_tolerance=on_fingers if watch == "goal" else {}))
    steps = 0
    while not h.outcome.done:
        world.step(6)
        steps += 6
        if steps == 60:  # 0.2 s into the lift
            world.set_block_pose("red", (0.0, 0.25, 0.015), 0.0)
    fingers = np.mean([world.joint_positions()[n] for n in m.FINGER_JOINTS])
    arm = np.array([world.joint_positions()[n] for n in m.ARM_JOINTS])
    if watch != "path":
        assert np.abs(arm - ABOVE_Q).max() < 0.02
        assert fingers < held - 0.1  # closed on nothing
        if watch is None:
            assert h.outcome.status == ac.SUCCEEDED
            return
        assert h.outcome.error_code == ac.GOAL_TOLERANCE_VIOLATED, h.outcome
        assert ac.fingers_moved(h.outcome.error_code, h.outcome.message), h.outcome
        return
    assert h.outcome.error_code == ac.PATH_TOLERANCE_VIOLATED, h.outcome
    assert ac.fingers_moved(h.outcome.error_code, h.outcome.message), h.outcome
    world.step(60)  # stopped: the arm holds where the fingers moved, short of the lift
    after = np.array([world.joint_positions()[n] for n in m.ARM_JOINTS])
    assert np.abs(after - arm).max() < 0.02
    assert np.abs(after - GRASP_Q).max() < 0.5 * np.abs(np.subtract(ABOVE_Q, GRASP_Q)).max()


@pytest.mark.parametrize(
    ("kwargs", "param"),
    [
        ({"num_blocks": 9}, "num_blocks"),
        ({"num_blocks": 8, "block_colors": ("red",) * 8}, "block_colors"),
        ({"block_colors": ("red", "mauve", "blue", "green")}, "block_colors"),
        ({"physics_rate": -10.0}, "physics_rate"),
        ({"block_size": (0.04, 0.04)}, "block_size"),
        ({"model": "450_6m90a"}, "model"),
    ],
)
def test_invalid_config_names_the_parameter(kwargs, param):
    with pytest.raises(ConfigError) as err:
        SimConfig(**kwargs).validate()
    assert err.value.param == param and param in str(err.value)


def _arm_links_drawn(world) -> set[int]:
    """The arm's link indices with a pixel in the image, by the renderer's segmentation."""
    cam = world.camera
    _, _, _, _, seg = p.getCameraImage(
        cam.width, cam.height, cam.view_matrix(), cam.projection_matrix(),
        renderer=p.ER_TINY_RENDERER, flags=p.ER_SEGMENTATION_MASK_OBJECT_AND_LINKINDEX,
        physicsClientId=world._cid)
    seg = np.asarray(seg).reshape(cam.height, cam.width)
    arm = (seg >= 0) & ((seg & ((1 << 24) - 1)) == world.arm)
    return {int(i) for i in np.unique((seg[arm] >> 24) - 1)}


def test_parked_arm_is_out_of_the_camera_view(world):
    """The renderer's own segmentation: no pixel shows the arm beyond its base and pan link."""
    world.reset(0)
    world.set_arm_positions(m.PARK_POSE, m.GRIPPER_OPEN)
    assert not {i for i in _arm_links_drawn(world)
                if i >= world.joint_index["katana_motor2_lift_joint"]}
    # and the check can fail: with the arm over the table, its links are in the image
    world.set_arm_positions([0.0, 1.234239, -1.075592, 1.729443, 0.0])  # tool at (0.2, 0, 0.1)
    assert max(_arm_links_drawn(world)) >= 1


_LIMITS = [m.JOINT_LIMITS[name] for name in m.ARM_JOINTS]


@settings(max_examples=40, deadline=None)
@given(st.tuples(*(st.floats(lo, hi) for lo, hi in _LIMITS)))
def test_an_arm_out_of_view_has_no_reaching_link_in_the_image(world, q):
    """arm_in_view (bounding boxes) never says 'out of view' for a pose whose forearm, wrist,
    gripper or fingers the renderer draws; the fast sim images the scene only then."""
    world.set_arm_positions(q, m.GRIPPER_OPEN)
    reaching = world.link_index[FIRST_REACHING_LINK]
    drawn = {i for i in _arm_links_drawn(world) if i >= reaching}
    assert world.arm_in_view() or not drawn, (q, drawn)


def test_arm_in_view_tells_the_parked_arm_from_one_over_the_table(world):
    world.set_arm_positions(m.PARK_POSE, m.GRIPPER_OPEN)
    assert not world.arm_in_view()
    world.set_arm_positions([0.0, 1.234239, -1.075592, 1.729443, 0.0])  # tool at (0.2, 0, 0.1)
    assert world.arm_in_view()
    assert max(_arm_links_drawn(world)) >= world.link_index[FIRST_REACHING_LINK]
    world.set_arm_positions(m.PARK_POSE, m.GRIPPER_OPEN)  # the answer follows the pose
    assert not world.arm_in_view()


def test_a_still_scene_is_drawn_once_and_any_change_draws_it_anew(monkeypatch):
    w = PhysicsSim(SimConfig(num_blocks=3, seed=4))
    try:
        drawn = []
        raw = w._raw_render
        monkeypatch.setattr(w, "_raw_render", lambda *a: drawn.append(1) or raw(*a))
        first = w.render()
        w.advance_clock(1.0)  # the fast sim while idle: time passes, nothing moves
        again = w.render()
        assert len(drawn) == 1 and again is first
        assert np.array_equal(first, w.render(fresh=True))  # the cache is what a draw gives
        assert not first.flags.writeable  # nobody can spoil it for the next caller
        w.set_block_pose("red", (0.25, 0.05, 0.015), 0.3)
        moved = w.render()
        assert len(drawn) == 3 and not np.array_equal(moved, first)
        goal = TrajectoryGoal(list(m.ARM_JOINTS), [1.0], [[-2.0, *m.PARK_POSE[1:]]])
        w.start_trajectory(goal)
        w.step(24)  # the arm moved: the image must show it
        assert len(drawn) == 3
        w.render()
        assert len(drawn) == 4
    finally:
        w.close()


def test_fingers_moved_out_of_view_draw_nothing_new_and_the_cache_is_what_a_draw_gives(
        monkeypatch):
    """The parked arm opening its fingers changes nothing the camera sees: the image is not
    drawn again, and what is given back equals a fresh draw; the same fingers over the table
    are drawn anew."""
    w = PhysicsSim(SimConfig(num_blocks=3, seed=4))
    try:
        drawn = []
        raw = w._raw_render
        monkeypatch.setattr(w, "_raw_render", lambda *a: drawn.append(1) or raw(*a))
        w.set_arm_positions(m.PARK_POSE, m.GRIPPER_CLOSED)
        first = w.render()
        w.set_arm_positions(m.PARK_POSE, m.GRIPPER_OPEN)
        assert not w.arm_in_view()
        again = w.render()
        assert len(drawn) == 1 and again is first
        assert np.array_equal(again, w.render(fresh=True))
        over = [0.0, 1.234239, -1.075592, 1.729443, 0.0]  # tool at (0.2, 0, 0.1)
        w.set_arm_positions(over, m.GRIPPER_CLOSED)
        closed = w.render()
        w.set_arm_positions(over, m.GRIPPER_OPEN)
        opened = w.render()
        assert len(drawn) == 4 and not np.array_equal(closed, opened)
    finally:
        w.close()


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.05, 2.0), min_size=1, max_size=5),
       st.integers(0, 2**32 - 1), st.booleans(), st.lists(st.floats(-0.5, 3.0), max_size=20))
def test_the_sampled_trajectory_is_the_cubic_hermite_spline_through_the_goal(gaps, seed,
                                                                          with_velocities,
                                                                          when):
    """Checked against SciPy's CubicHermiteSpline (an independent implementation)."""
    rng = np.random.default_rng(seed)
    times = np.cumsum(gaps)
    points = rng.uniform(-1.0, 1.0, (len(times), 5))
    vels = rng.uniform(-0.3, 0.3, (len(times), 5)) if with_velocities else None
    start = rng.uniform(-1.0, 1.0, 5)
    goal = TrajectoryGoal(list(m.ARM_JOINTS), times.tolist(), points.tolist(),
                          vels.tolist() if vels is not None else None)
    follower = ctl.TrajectoryFollower(goal, ac.ArmContract(), 0.0, start)  # as PhysicsSim
    knots = np.concatenate([[0.0], times])
    q = np.vstack([start, points])
    v = np.vstack([np.zeros(5), vels if vels is not None else np.zeros_like(points)])
    spline = CubicHermiteSpline(knots, q, v)
    t = np.clip(np.array(when, float) * times[-1], 0.0, None)
    pos, vel = follower.sample_many(t)
    inside = t < times[-1]
    assert np.allclose(pos[inside], spline(t[inside]), atol=1e-9)
    assert np.allclose(vel[inside & (t > 0)], spline(t[inside & (t > 0)], 1), atol=1e-8)
    assert np.allclose(pos[~inside], points[-1]) and not vel[~inside].any()  # held at the end
    one_q, one_v = follower.sample(times[-1] / 3)
    assert np.allclose(one_q, spline(times[-1] / 3)) and np.allclose(one_v,
                                                                       spline(times[-1] / 3, 1))


@settings(max_examples=20, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=len(m.ALL_JOINTS), max_size=len(m.ALL_JOINTS)))
def test_joint_damping_is_stable_at_the_slowest_physics_rate(world, unit):
    """Bullet applies a joint's damping c explicitly: a velocity is scaled by 1 - c dt / I each
    step, which diverges once c dt / I > 2 (I the joint's own inertia, the mass matrix's
    diagonal). Checked with PyBullet's mass matrix at poses across the joint ranges, at the
    slowest rate the sim allows (60 Hz), against the damping the sim loaded."""
    q = [lo + (hi - lo) * (u + 1.0) / 2.0
         for u, (lo, hi) in zip(unit, (m.JOINT_LIMITS[n] for n in m.ALL_JOINTS), strict=True)]
    inertia = np.diag(np.array(p.calculateMassMatrix(world.arm, q, physicsClientId=world._cid)))
    damping = np.array([p.getJointInfo(world.arm, i, physicsClientId=world._cid)[6]
                        for i in world._all_idx])
    assert damping.min() > 0.0
    assert np.all(damping * (1.0 / 60.0) / inertia < 1.0), dict(
        zip(m.ALL_JOINTS, np.round(damping / 60.0 / inertia, 2), strict=True))


def test_fingers_knocked_hard_come_back_to_rest(world):
    """Seen in a skill trial: a falling block struck an open finger; with the damping of the
    arm's joints (0.05) the fingers then swung +-52 rad/s every step for good, and every later
    move failed as 'still moving'. Knocked at 60 rad/s, they settle within half a second."""
    world.set_arm_positions(m.PARK_POSE, 0.2)
    for i in world._finger_idx:
        p.resetJointState(world.arm, i, 0.2, 60.0, physicsClientId=world._cid)
    world.step(int(0.5 / world.dt))
    pos, vel, _ = world.joint_state()
    assert np.all(np.abs(vel) < 0.05), vel
    np.testing.assert_allclose(pos[5:], 0.2, atol=0.01)
