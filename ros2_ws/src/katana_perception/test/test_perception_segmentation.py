"""Segmentation against ground truth on rendered scenes (synthetic renderer).

A block counts as visible when at least 40% of its top face is in view; every visible block
must be found within 5 mm and 5 degrees (modulo 90: a square top), no detection may be
invented, and `complete` (nothing rests on it) must match the scene.
"""

import math

import numpy as np
import pytest
from katana_perception.core.calibration import Calibration
from katana_perception.core.colors import NOMINAL_RGB, parse_color_entry, parse_color_table
from katana_perception.core.segmentation import Segmenter, check_rgb, wrap_quarter
from katana_perception.core.synthetic import (
    Renderer,
    SceneBlock,
    random_scene,
    stack_block,
    visible_fraction,
)

CALIB = Calibration.overhead_default()
VISIBLE = 0.4


def yaw_error_deg(a: float, b: float) -> float:
    return abs(math.degrees(wrap_quarter(a - b)))


def covered_names(scene: list[SceneBlock]) -> set[str]:
    """random_scene lists stacks bottom first: a block followed by level + 1 is covered."""
    return {b.name for b, n in zip(scene, scene[1:], strict=False) if n.level == b.level + 1}


def check_scene(seed: int, seg: Segmenter, max_height: int, levels_known: bool = True) -> dict:
    rng = np.random.default_rng(seed)
    names = list(NOMINAL_RGB)[: int(rng.integers(4, 9))]
    scene = random_scene(rng, names, max_height=max_height)
    renderer = Renderer(CALIB, light=(rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), 1.0),
                        ambient=float(rng.uniform(0.3, 0.6)),
                        noise_sigma=float(rng.uniform(0.0, 4.0)))
    img, ids = renderer.render(scene, seed=seed)
    vis = visible_fraction(renderer, scene, ids)
    levels = {b.name: b.level for b in scene} if levels_known else None
    dets = {d.color: d for d in seg.segment(img, CALIB, levels)}
    covered = covered_names(scene)
    stats = {"checked": 0}
    for name, d in dets.items():
        assert vis[name] > 0.05, f"seed {seed}: {name} detected but its top is not in view"
        assert d.complete == (name not in covered), f"seed {seed}: {name} complete={d.complete}"
    for b in scene:
        if vis[b.name] < VISIBLE:
            continue
        assert b.name in dets, f"seed {seed}: visible {b.name} ({vis[b.name]:.0%}) not found"
        d = dets[b.name]
        z = b.level * b.size[2]
        x, y = CALIB.pixel_to_world(d.u, d.v, z)
        err = math.hypot(float(x) - b.x, float(y) - b.y)
        assert err <= 0.005, f"seed {seed}: {b.name} centroid off by {err * 1000:.1f} mm"
        yaw = CALIB.image_angle_to_yaw(d.u, d.v, d.angle, z)
        assert yaw_error_deg(yaw, b.yaw) <= 5.0, f"seed {seed}: {b.name} yaw off"
        stats["checked"] += 1
    return stats


def test_scatters_and_stacks_many_scenes():
    seg = Segmenter()
    checked = sum(check_scene(seed, seg, max_height=3)["checked"] for seed in range(150))
    assert checked > 450  # the scenes really exercised the checks


def test_scatters_without_memory_levels():
    """On a plain scatter every block is on the table: level 1 is the right default."""
    seg = Segmenter()
    for seed in range(1000, 1040):
        check_scene(seed, seg, max_height=1, levels_known=False)


def test_partly_covered_block_is_found_and_flagged():
    scene = [stack_block("green", 0.24, -0.08, 1, 0.2), stack_block("blue", 0.255, -0.08, 2, 0.2)]
    renderer = Renderer(CALIB, noise_sigma=0.0)
    img, ids = renderer.render(scene)
    vis = visible_fraction(renderer, scene, ids)
    assert 0.4 <= vis["green"] < 0.9
    dets = {d.color: d for d in Segmenter().segment(img, CALIB, {"green": 1, "blue": 2})}
    assert not dets["green"].complete and dets["blue"].complete
    x, y = CALIB.pixel_to_world(dets["green"].u, dets["green"].v, 0.03)
    assert math.hypot(float(x) - 0.24, float(y) + 0.08) < 0.005
    # The blob's own centroid is far off: the known-size square fit is what makes it right.
    px = dets["green"].pixels().mean(axis=0)
    bx, by = CALIB.pixel_to_world(px[0], px[1], 0.03)
    assert math.hypot(float(bx) - 0.24, float(by) + 0.08) > 0.008


def test_side_faces_do_not_bias_the_centre():
    """Far from the nadir the blob includes a side face; the top-face fit removes its bias."""
    b = stack_block("red", 0.15, 0.15, 1, 0.0)
    renderer = Renderer(CALIB, noise_sigma=0.0, ambient=0.9)  # side faces bright: segmented
    img, _ = renderer.render([b])
    d = Segmenter().segment(img, CALIB)[0]
    gt = renderer.top_centre_pixel(b)
    assert np.hypot(d.u - gt[0], d.v - gt[1]) < 1.0
    blob = d.pixels().mean(axis=0)
    assert np.hypot(blob[0] - gt[0], blob[1] - gt[1]) > 2.0


def test_fully_covered_block_shows_only_slivers_and_is_not_reported():
    scene = [stack_block("green", 0.16, 0.12, 1, 0.1), stack_block("red", 0.16, 0.12, 2, 0.1)]
    img, ids = Renderer(CALIB, noise_sigma=0.0, ambient=0.9).render(scene)
    assert (ids == 0 * 8 + 2).sum() + (ids == 0 * 8 + 1).sum() + (ids == 0 * 8 + 3).sum() > 50
    assert [d.color for d in Segmenter().segment(img, CALIB, {"green": 1, "red": 2})] == ["red"]


def test_empty_table_and_grey_objects_give_nothing():
    grey = SceneBlock("red", 0.2, 0.0, 0.05, size=(0.1, 0.1, 0.1), rgb=(0.3, 0.3, 0.3))
    img, _ = Renderer(CALIB).render([grey])
    assert Segmenter().segment(img, CALIB) == []


@pytest.mark.parametrize("bad", [
    np.zeros((480, 640), np.uint8),
    np.zeros((480, 640, 4), np.uint8),
    np.zeros((480, 640, 3), np.float32),
    np.zeros((4, 4, 3), np.uint8),
    [[1, 2, 3]],
])
def test_malformed_images_are_rejected_with_a_reason(bad):
    with pytest.raises(ValueError, match="image"):
        check_rgb(bad)
    with pytest.raises(ValueError):
        Segmenter().segment(bad)


def test_colour_table_parsing():
    c = parse_color_entry("red:0-7,172-179")
    assert c.name == "red" and c.hues == ((0, 7), (172, 179))
    assert parse_color_entry(c.to_string()) == c
    for bad in ("red", "red:7", "red:0-200", "red:9-3", ":0-5", "a b:0-5"):
        with pytest.raises(ValueError):
            parse_color_entry(bad)
    with pytest.raises(ValueError, match="unique"):
        parse_color_table(["red:0-5", "red:170-179"])
