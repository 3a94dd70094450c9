"""Segmentation on real PyBullet renders of katana_sim, against the sim's ground truth."""

import math

import katana_sim.core as sim  # a declared test_depend: fail, never skip
import numpy as np
import pybullet
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from katana_description.models import stands_upright
from katana_perception.core.calibration import Calibration
from katana_perception.core.memory import Block, footprint_overlap
from katana_perception.core.segmentation import Segmenter, wrap_quarter
from katana_perception.messages import detection_to_msg


@pytest.fixture(scope="module")
def world():
    w = sim.PhysicsSim(sim.SimConfig(num_blocks=8, seed=0))
    yield w
    w.close()


def calibration_of(world) -> Calibration:
    cam = world.camera
    return Calibration.from_camera_rpy(cam.K, cam.position, cam.rpy, cam.width, cam.height)


def check(world, seg: Segmenter, calib: Calibration) -> int:
    truth = world.ground_truth()
    dets = {d.color: d for d in seg.segment(world.render(), calib,
                                            {b.id: b.level for b in truth})}
    gt = {b.id: b for b in truth}
    for name, d in dets.items():
        assert name in gt, f"invented {name}"
        assert d.complete == gt[name].on_top, f"{name}: complete {d.complete}"
    n = 0
    for b in truth:
        if not b.visible or b.tilted:
            continue
        assert b.id in dets, f"visible {b.id} not found"
        d = dets[b.id]
        z = b.level * b.size[2]
        x, y = calib.pixel_to_world(d.u, d.v, z)
        err = math.hypot(float(x) - b.position[0], float(y) - b.position[1])
        assert err <= 0.005, f"{b.id}: {err * 1000:.1f} mm"
        yaw = calib.image_angle_to_yaw(d.u, d.v, d.angle, z)
        assert abs(math.degrees(wrap_quarter(yaw - b.yaw))) <= 5.0, f"{b.id}: yaw"
        n += 1
    return n


def test_sim_scatters(world):
    seg, calib = Segmenter(), calibration_of(world)
    n = 0
    for seed in range(12):
        world.reset(seed=seed)
        n += check(world, seg, calib)
    assert n >= 12 * 7  # nearly all 8 blocks of every scatter were checked


def test_sim_stacks(world):
    seg, calib = Segmenter(), calibration_of(world)
    rng = np.random.default_rng(5)
    n = 0
    for seed in range(10):
        world.reset(seed=100 + seed)
        ids = list(world.blocks)
        rng.shuffle(ids)
        # two stacks: of three and of two blocks, small random offsets
        for below, above in ((ids[0], ids[1]), (ids[1], ids[2]), (ids[3], ids[4])):
            dx, dy = rng.uniform(-0.008, 0.008, size=2)
            world.stack(above, on=below, dx=float(dx), dy=float(dy))
        world.settle()
        truth = {b.id: b for b in world.ground_truth()}
        assert truth[ids[2]].level == 3 and truth[ids[4]].level == 2
        n += check(world, seg, calib)
    assert n >= 10 * 5


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(radius=st.floats(0.12, 0.38), bearing=st.floats(-2.4, 2.4),
       yaw=st.floats(-math.pi, math.pi), pose=st.sampled_from(["upright", "rolled", "pitched"]),
       turn=st.sampled_from([-1, 1]))
def test_a_block_on_its_side_is_told_from_an_upright_one_against_the_sim(
        world, radius, bearing, yaw, pose, turn):
    """Rendered by PyBullet, judged against its ground truth (tilted): a fully visible block
    is reported upright or on its side, and the message gives the footprint it lies on."""
    seg, calib = Segmenter(), calibration_of(world)
    x, y = radius * math.cos(bearing), radius * math.sin(bearing)
    roll, pitch, z = {"upright": (0.0, 0.0, 0.015), "rolled": (turn * math.pi / 2, 0.0, 0.02),
                      "pitched": (0.0, turn * math.pi / 2, 0.02)}[pose]
    for b in world.blocks:  # the others out of the way, beyond the table's far edge
        world.set_block_pose(b, (0.9, 0.6 - 0.1 * list(world.blocks).index(b), 0.015))
    world.set_block_pose("red", (x, y, z), quaternion=pybullet.getQuaternionFromEuler(
        (roll, pitch, yaw)))
    truth = next(b for b in world.ground_truth() if b.id == "red")
    dets = {d.color: d for d in seg.segment(world.render(), calib, {"red": 1})}
    assume("red" in dets and dets["red"].complete and truth.visible)
    d = dets["red"]
    assert stands_upright(d.size) == (not truth.tilted), (d.size, pose)
    msg = detection_to_msg(d, calib)
    reported = Block("red", "red", msg.pose.position.x, msg.pose.position.y, msg.yaw,
                     size=(msg.size.x, msg.size.y, msg.size.z))
    # the true footprint: the box's horizontal extents in the world, from its rotation
    rot = np.array(pybullet.getMatrixFromQuaternion(truth.quaternion)).reshape(3, 3)
    extents = np.abs(rot) @ np.asarray(truth.size)  # world-axis extents of the rotated box
    footprint = Block("red", "red", truth.position[0], truth.position[1], 0.0,
                      size=(float(extents[0]), float(extents[1]), float(extents[2])))
    if not truth.tilted:  # upright: the footprint turns with the yaw
        footprint.size, footprint.yaw = tuple(truth.size), truth.yaw
    else:  # on its side: the box's long horizontal edge is its body z or x/y axis
        horizontal = [k for k in range(3) if abs(rot[2, k]) < 0.5]
        k_long = max(horizontal, key=lambda k: truth.size[k])
        footprint.yaw = math.atan2(rot[1, k_long], rot[0, k_long])
        footprint.size = (truth.size[k_long], min(truth.size[k] for k in horizontal),
                          float(extents[2]))
    assert abs(msg.size.z - footprint.size[2]) < 1e-6
    assert msg.pose.position.z == pytest.approx(truth.position[2], abs=0.002)
    assert footprint_overlap(reported, footprint) >= 0.85, (reported, footprint)
