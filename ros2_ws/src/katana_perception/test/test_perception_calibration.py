"""Calibration: projection against an independent pinhole computation, round trips, solvePnP
recovery from rendered blocks, the YAML files and the katana-calibrate command."""

import math
import os

import cv2
import katana_sim.core as sim
import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_perception.calibrate_cli import calibrate
from katana_perception.calibrate_cli import main as calibrate_main
from katana_perception.core.calibration import (
    Calibration,
    default_camera_matrix,
    load_camera_info_yaml,
    solve_extrinsics,
)
from katana_perception.core.segmentation import Segmenter
from katana_perception.core.synthetic import Renderer, stack_block
from scipy.spatial.transform import Rotation

angles = st.floats(-0.15, 0.15)


def tilted(droll: float, dpitch: float, dyaw: float, pos=(0.22, 0.0, 0.75)) -> Calibration:
    return Calibration.from_camera_rpy(default_camera_matrix(), pos,
                                       (math.pi + droll, dpitch, -math.pi / 2 + dyaw))


def pinhole(calib: Calibration, p: np.ndarray) -> np.ndarray:
    """Independent projection: x = K (R_wc^T (p - C)), no OpenCV."""
    r_wc = Rotation.from_quat(calib.orientation_xyzw).as_matrix()
    cam = (p - calib.centre) @ r_wc
    uvw = cam @ calib.K.T
    return uvw[:, :2] / uvw[:, 2:3]


def test_default_camera_matches_the_shared_scene():
    c = Calibration.overhead_default()
    u, v = c.world_to_pixel([0.22, 0.30, 0.22], [0.0, 0.0, 0.10], [0.0, 0.0, 0.0])
    assert np.allclose(u, [319.5, 319.5, 219.5]) and np.allclose(v, [239.5, 159.5, 239.5])
    assert c.pixels_per_metre(319.5, 239.5, 0.0) == pytest.approx(1000.0)
    assert np.allclose(c.nadir(), [319.5, 239.5])


def test_default_camera_agrees_with_the_sim_camera_model():
    cam = sim.CameraModel()
    c = Calibration.from_camera_rpy(cam.K, cam.position, cam.rpy, cam.width, cam.height)
    pts = np.random.default_rng(0).uniform([0.1, -0.2, 0.0], [0.35, 0.2, 0.15], size=(50, 3))
    assert np.allclose(c.project(pts), cam.project(pts), atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(angles, angles, st.floats(-math.pi, math.pi), st.floats(0.0, 0.12),
       st.floats(0.1, 0.35), st.floats(-0.2, 0.2))
def test_projection_matches_pinhole_and_round_trips(dr, dp, dy, z, x, y):
    c = tilted(dr, dp, dy)
    p = np.array([[x, y, z]])
    uv = c.project(p)
    assert np.allclose(uv, pinhole(c, p), atol=1e-6)
    bx, by = c.pixel_to_world(uv[0, 0], uv[0, 1], z)
    assert math.hypot(float(bx) - x, float(by) - y) < 1e-9


def test_round_trip_with_distortion():
    c = Calibration.from_camera_rpy(default_camera_matrix(), (0.22, 0, 0.75),
                                    (math.pi, 0, -math.pi / 2), D=[-0.08, 0.02, 0.001, -0.001, 0])
    xs, ys = np.meshgrid(np.linspace(0.12, 0.32, 7), np.linspace(-0.18, 0.18, 7))
    u, v = c.world_to_pixel(xs, ys, np.full(xs.shape, 0.03))
    bx, by = c.pixel_to_world(u, v, np.full(xs.shape, 0.03))
    assert np.abs(bx - xs).max() < 1e-5 and np.abs(by - ys).max() < 1e-5


def test_yaw_and_image_angle_are_inverse():
    c = tilted(0.05, -0.04, 0.3)
    for yaw in np.linspace(-3, 3, 13):
        a = c.yaw_to_image_angle(0.2, 0.05, yaw, 0.03)
        u, v = c.world_to_pixel(0.2, 0.05, 0.03)
        assert math.isclose(math.remainder(c.image_angle_to_yaw(float(u), float(v), a, 0.03)
                                           - yaw, 2 * math.pi), 0.0, abs_tol=1e-6)


def test_bad_inputs_are_rejected():
    with pytest.raises(ValueError, match="quaternion"):
        Calibration.from_camera_pose(default_camera_matrix(), (0, 0, 1), (0, 0, 0, 0))
    with pytest.raises(ValueError, match="pinhole"):
        Calibration(K=np.zeros((3, 3)), rvec=np.zeros(3), tvec=np.zeros(3))
    with pytest.raises(ValueError, match="at least 4"):
        solve_extrinsics(np.zeros((3, 3)), np.zeros((3, 2)), default_camera_matrix(),
                         np.zeros(5), 640, 480)


def overhead(K: np.ndarray, D) -> Calibration:
    return Calibration.from_camera_rpy(K, (0.22, 0, 0.75), (math.pi, 0, -math.pi / 2), D=D)


@pytest.mark.parametrize("f, D", [
    (750.0, [0.0] * 5), (750.0, [-0.08, 0.02, 0.001, -0.001, 0]), (750.0, [0.2, -0.2, 0, 0, 0]),
    (300.0, [-0.35, 0.12, 0, 0, -0.02]), (200.0, [-0.3, 0.1, 0, 0, 0])])
def test_real_lenses_are_plausible(f, D):
    """The overhead camera, and lenses from narrow to 116 degrees with real distortion."""
    assert overhead(default_camera_matrix(f=f), D).implausibility() == ""


@pytest.mark.parametrize("K, D, why", [
    ([[1e12, 0, 319.5], [0, 1e12, 239.5], [0, 0, 1]], None, "field of view is 3.67e-08"),
    ([[0.5, 0, 319.5], [0, 750, 239.5], [0, 0, 1]], None, "horizontal field of view is 180"),
    ([[750, 0, 1e12], [0, 750, 239.5], [0, 0, 1]], None, "principal point"),
    ([[750, 0, 319.5], [0, 750, -3], [0, 0, 1]], None, "principal point"),
    (default_camera_matrix(), [1e12, 0, 0, 0, 0], "cannot be inverted"),
    (default_camera_matrix(), [10.0, 0, 0, 0, 0], "cannot be inverted"),
    (default_camera_matrix(f=200.0), [-0.35, 0.12, 0, 0, -0.02], "cannot be inverted"),
])
def test_implausible_cameras_say_why(K, D, why):
    assert why in overhead(np.asarray(K, float), D).implausibility()


def test_a_camera_that_does_not_see_the_table_is_implausible():
    up = Calibration.from_camera_rpy(default_camera_matrix(), (0.22, 0, 0.75), (0, 0, 0))
    assert "sees the table" in up.implausibility()


@settings(max_examples=80, deadline=None)
@given(f=st.floats(1.0, 1e6), cx=st.floats(-100.0, 800.0), k1=st.floats(-50.0, 50.0),
       k3=st.sampled_from([0.0, -0.02, 1.0, -5.0]), x=st.floats(0.14, 0.30),
       y=st.floats(-0.12, 0.12))
def test_a_plausible_camera_projects_the_table_it_sees_to_drawable_pixels(f, cx, k1, k3, x, y):
    """Whatever the intrinsics, a calibration that passes projects a table point under the
    image's middle to a finite pixel that maps back to it (the fovea can draw it)."""
    K = np.array([[f, 0.0, cx], [0.0, f, 239.5], [0.0, 0.0, 1.0]])
    c = overhead(K, [k1, 0.0, 0.0, 0.0, k3])
    if c.implausibility():
        return
    u, v = c.pixel_to_world(np.array([0.25, 0.75]) * 639, np.array([0.25, 0.75]) * 479, 0.0)
    if not (min(u) <= x <= max(u) and min(v) <= y <= max(v)):
        return  # not under the image's middle
    pu, pv = c.world_to_pixel(x, y, 0.0)
    assert np.isfinite([pu, pv]).all() and max(abs(pu), abs(pv)) < 2**26
    bx, by = c.pixel_to_world(pu, pv, 0.0)
    assert math.hypot(float(bx) - x, float(by) - y) < 0.01


def mapping_error(est: Calibration, truth: Calibration) -> float:
    """Worst table-plane error over the play area at every block height, m."""
    gx, gy = np.meshgrid(np.linspace(0.14, 0.3, 9), np.linspace(-0.16, 0.16, 9))
    worst = 0.0
    for z in (0.0, 0.03, 0.06, 0.09, 0.12):
        u, v = truth.world_to_pixel(gx, gy, np.full(gx.shape, z))
        bx, by = est.pixel_to_world(u, v, np.full(gx.shape, z))
        worst = max(worst, float(np.hypot(bx - gx, by - gy).max()))
    return worst


def test_solvepnp_recovers_a_tilted_camera_from_noisy_points():
    truth = tilted(0.06, -0.05, 0.2, pos=(0.21, 0.02, 0.74))
    rng = np.random.default_rng(1)
    world = np.column_stack([rng.uniform(0.14, 0.3, 8), rng.uniform(-0.15, 0.15, 8),
                             np.where(np.arange(8) % 2 == 0, 0.03, 0.09)])
    pixels = truth.project(world) + rng.normal(0, 0.3, (8, 2))
    est, rms, _ = solve_extrinsics(world, pixels, truth.K, truth.D, 640, 480)
    assert rms < 1.0
    assert mapping_error(est, truth) < 0.0015
    assert np.linalg.norm(est.centre - truth.centre) < 0.01
    rel = Rotation.from_matrix(est.R @ truth.R.T).magnitude()
    assert math.degrees(rel) < 0.5


def test_noise_free_planar_points_are_exact():
    truth = tilted(0.06, -0.05, 0.2, pos=(0.21, 0.02, 0.74))
    rng = np.random.default_rng(2)
    world = np.column_stack([rng.uniform(0.14, 0.3, 6), rng.uniform(-0.15, 0.15, 6),
                             np.full(6, 0.03)])
    est, rms, _ = solve_extrinsics(world, truth.project(world), truth.K, truth.D, 640, 480)
    assert rms < 1e-6 and mapping_error(est, truth) < 1e-6


def test_yaml_files_round_trip(tmp_path):
    c = tilted(0.03, 0.02, -0.1)
    c.save(tmp_path / "camera_info.yaml", tmp_path / "extrinsics.yaml", rms_px=0.4)
    info = yaml.safe_load((tmp_path / "camera_info.yaml").read_text())
    for key in ("image_width", "image_height", "camera_name", "camera_matrix",
                "distortion_model", "distortion_coefficients", "rectification_matrix",
                "projection_matrix"):
        assert key in info
    assert info["camera_matrix"]["rows"] == 3 and len(info["camera_matrix"]["data"]) == 9
    back = Calibration.load(tmp_path / "camera_info.yaml", tmp_path / "extrinsics.yaml")
    assert np.allclose(back.K, c.K) and np.allclose(back.centre, c.centre)
    assert np.allclose(back.R, c.R, atol=1e-9)
    (tmp_path / "bad.yaml").write_text("just: text\n")
    with pytest.raises(ValueError, match="camera_info"):
        load_camera_info_yaml(tmp_path / "bad.yaml")


BLOCKS = {"red": (0.17, 0.10, 1), "green": (0.27, -0.11, 1), "blue": (0.16, -0.08, 1),
          "yellow": (0.28, 0.08, 2), "orange": (0.22, 0.0, 3)}
HIDDEN = {"purple": (0.28, 0.08, 1), "magenta": (0.22, 0.0, 1), "cyan": (0.22, 0.0, 2)}


def rendered_table(tmp_path, truth: Calibration):
    scene = [stack_block(n, x, y, lv, 0.2 * i)
             for i, (n, (x, y, lv)) in enumerate(BLOCKS.items())]
    scene += [stack_block(n, x, y, lv, 0.0) for n, (x, y, lv) in HIDDEN.items()]
    img, _ = Renderer(truth).render(scene)
    path = tmp_path / "table.png"
    cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    points = tmp_path / "points.yaml"
    points.write_text(yaml.safe_dump({"blocks": {k: list(v) for k, v in BLOCKS.items()}}))
    return path, points


def test_katana_calibrate_recovers_the_camera(tmp_path, capsys):
    truth = tilted(0.04, -0.03, 0.05, pos=(0.225, 0.01, 0.76))
    image, points = rendered_table(tmp_path, truth)
    out = tmp_path / "calib"
    code = calibrate_main(["--image", str(image), "--points", str(points), "--fx", "750",
                           "--out-dir", str(out)])
    assert code == 0, capsys.readouterr().err
    est = Calibration.load(out / "camera_info.yaml", out / "extrinsics.yaml")
    # The synthetic renderer's anti-aliasing grows silhouettes by about half a pixel, which
    # reads as a slightly nearer camera; the PyBullet test below holds a tighter bound.
    assert mapping_error(est, truth) < 0.005  # table points land where they are
    assert np.linalg.norm(est.centre - truth.centre) < 0.03
    assert math.degrees(Rotation.from_matrix(est.R @ truth.R.T).magnitude()) < 0.5
    assert "one height" not in capsys.readouterr().err
    # The same through a camera_info YAML instead of --fx.
    code = calibrate_main(["--image", str(image), "--points", str(points), "--camera-info",
                           str(out / "camera_info.yaml"), "--out-dir", str(tmp_path / "c2")])
    assert code == 0


def test_calibration_from_pybullet_views():
    cam = sim.CameraModel(position=(0.225, 0.01, 0.76),
                          rpy=(math.pi + 0.04, -0.03, -math.pi / 2 + 0.05))
    truth = Calibration.from_camera_rpy(cam.K, cam.position, cam.rpy)
    world = sim.PhysicsSim(sim.SimConfig(num_blocks=8, camera=cam))
    views = []
    try:
        for seed in range(2):
            world.reset(seed=seed)
            ids = list(world.blocks)
            world.stack(ids[1], on=ids[0])
            world.stack(ids[3], on=ids[2])
            world.stack(ids[4], on=ids[3])
            world.settle()
            known = {b.id: (b.position[0], b.position[1], b.level)
                     for b in world.ground_truth() if b.visible}
            views.append((world.render(), known, [], []))
    finally:
        world.close()
    est, rms, _ = calibrate(views, cam.K, np.zeros(5), Segmenter(), (0.04, 0.04, 0.03))
    assert rms < 1.0
    assert mapping_error(est, truth) < 0.003


def test_katana_calibrate_explains_bad_usage(tmp_path, capsys):
    image, points = rendered_table(tmp_path, Calibration.overhead_default())
    with pytest.raises(SystemExit) as ex:
        calibrate_main(["--image", str(image), "--points", str(points)])
    assert ex.value.code == 2 and "intrinsics needed" in capsys.readouterr().err
    few = tmp_path / "few.yaml"
    few.write_text(yaml.safe_dump({"blocks": {"red": [0.17, 0.1], "blue": [0.16, -0.08]}}))
    flat = tmp_path / "flat.yaml"
    u, v = Calibration.overhead_default().world_to_pixel(0.3, -0.1, 0.03)
    flat.write_text(yaml.safe_dump({
        "blocks": {k: list(v[:2]) for k, v in BLOCKS.items() if v[2] == 1},
        "markers": [{"world": [0.3, -0.1, 0.03], "pixel": [float(u), float(v)]}]}))
    calibrate_main(["--image", str(image), "--points", str(flat), "--fx", "750",
                    "--out-dir", str(tmp_path / "f")])
    assert "every point is at one height" in capsys.readouterr().err
    assert calibrate_main(["--image", str(image), "--points", str(few), "--fx", "750"]) == 1
    assert "at least 4" in capsys.readouterr().err
    ghost = tmp_path / "ghost.yaml"
    ghost.write_text(yaml.safe_dump({"blocks": {**{k: list(v) for k, v in BLOCKS.items()},
                                                "cyan": [0.2, 0.1]}}))
    assert calibrate_main(["--image", str(image), "--points", str(ghost), "--fx", "750"]) == 1
    assert "blocks not found: cyan" in capsys.readouterr().err
    with pytest.raises(SystemExit) as ex:
        calibrate_main(["--image", str(image), "--image", str(image), "--points", str(points),
                        "--fx", "750"])
    assert ex.value.code == 2 and "one points file per image" in capsys.readouterr().err
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text(yaml.safe_dump({"blocks": {**{k: list(v) for k, v in BLOCKS.items()},
                                                "red": [0.25, 0.05]}}))
    assert calibrate_main(["--image", str(image), "--points", str(wrong), "--fx", "750",
                           "--out-dir", str(tmp_path / "w")]) == 1
    assert "exceeds --max-rms" in capsys.readouterr().err
    assert not (tmp_path / "w" / "extrinsics.yaml").exists()


def test_katana_calibrate_checks_every_option_before_any_work(tmp_path, capsys):
    image, points = rendered_table(tmp_path, Calibration.overhead_default())
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    afile = tmp_path / "a_file"
    afile.write_text("x")
    base = ["--image", str(image), "--points", str(points), "--fx", "750"]
    bad = [
        (["--image", str(tmp_path / "none.png"), "--points", str(points), "--fx", "750"],
         "--image"),
        (["--image", str(image), "--points", str(tmp_path / "none.yaml"), "--fx", "750"],
         "--points"),
        (["--image", str(image), "--points", str(points), "--camera-info",
          str(tmp_path / "none.yaml")], "--camera-info"),
        (["--image", str(image), "--points", str(points), "--fx", "-750"], "--fx"),
        (["--image", str(image), "--points", str(points), "--fx", "nan"], "--fx"),
        ([*base, "--fy", "0"], "--fy"),
        ([*base, "--cx", "-1"], "--cx"),
        ([*base, "--cy", "inf"], "--cy"),
        ([*base, "--max-rms", "-2"], "--max-rms"),
        ([*base, "--color-table", "red:0-400"], "--color-table"),
        ([*base, "--camera-name", " "], "--camera-name"),
        ([*base, "--out-dir", str(afile / "sub")], "--out-dir"),
        ([*base, "--bogus"], "--bogus"),
    ]
    if os.geteuid() != 0:  # root writes anywhere
        bad.append(([*base, "--out-dir", str(locked / "out")], "--out-dir"))
    for argv, option in bad:
        with pytest.raises(SystemExit) as ex:
            calibrate_main(argv)
        err = capsys.readouterr().err
        last = err.strip().splitlines()[-1]
        assert ex.value.code == 2 and "usage: katana-calibrate" in err, argv
        assert option in last, (argv, last)
    assert not list(tmp_path.glob("**/extrinsics.yaml"))  # nothing was written
