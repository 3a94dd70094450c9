"""Segmentation on real PyBullet renders of katana_sim, against the sim's ground truth."""

import math

import katana_sim.core as sim  # a declared test_depend: fail, never skip
import numpy as np
import pytest
from katana_perception.core.calibration import Calibration
from katana_perception.core.segmentation import Segmenter, wrap_quarter


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
