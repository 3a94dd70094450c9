"""The fovea's compiled path (FoveaScene) against its reference twin (FoveaSceneReference): the
same instances, in the same order, equal to the last bit, on random scenes."""

import math

import cv2
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_description.models import BLOCK_SIZE
from katana_perception.core import fovea_kernels
from katana_perception.core.calibration import Calibration
from katana_perception.core.colors import NOMINAL_RGB
from katana_perception.core.fovea import (
    N_ACTIONS,
    FoveaParams,
    FoveaScene,
    FoveaSceneReference,
    NotFound,
)
from katana_perception.core.memory import Block
from katana_sim.core.camera import CameraModel

NAMES = sorted(NOMINAL_RGB)
_CAM = CameraModel()
SIM_CALIB = Calibration.from_camera_rpy(_CAM.K, _CAM.position, _CAM.rpy, _CAM.width, _CAM.height)
CALIBS = [SIM_CALIB, Calibration.overhead_default()]
LYING = (BLOCK_SIZE[0], BLOCK_SIZE[2], BLOCK_SIZE[1])  # a block on its side: no stack level


@st.composite
def stacks(draw):
    """1-4 stacks of 1-4 blocks anywhere in the play area (they may overlap: ties and taller
    neighbours are part of the definition), each block offset and turned from the one below."""
    blocks: list[Block] = []
    for _ in range(draw(st.integers(1, 4))):
        x, y = draw(st.floats(0.12, 0.32)), draw(st.floats(-0.18, 0.18))
        yaw = draw(st.floats(-math.pi, math.pi))
        below = None
        for level in range(1, draw(st.integers(1, 4)) + 1):
            if level > 1:
                x += draw(st.floats(-0.012, 0.012))
                y += draw(st.floats(-0.012, 0.012))
                yaw += draw(st.floats(-0.3, 0.3))
            name = NAMES[len(blocks)] if len(blocks) < len(NAMES) else f"b{len(blocks)}"
            size = draw(st.sampled_from([BLOCK_SIZE] * 5 + [LYING]))
            blocks.append(Block(name, name, x, y, yaw, support=below, level=level, size=size))
            below = name
    return blocks


def rect_mask(calib: Calibration, u: float, v: float, w: float, h: float, deg: float):
    m = np.zeros((calib.height, calib.width), np.uint8)
    box = cv2.boxPoints(((u, v), (w, h), deg))
    cv2.fillPoly(m, [np.rint(box).astype(np.int32)], 1)
    return m.astype(bool)


@st.composite
def scenes(draw, with_masks: bool):
    calib = draw(st.sampled_from(CALIBS))
    blocks = draw(stacks())
    masks = None
    if with_masks:  # image masks of some blocks: rotated rectangles about their projection
        masks = {}
        for b in blocks:
            if draw(st.booleans()):
                u, v = (float(a) for a in calib.world_to_pixel(b.x, b.y, 0.03 * b.level))
                masks[b.id] = rect_mask(calib, u + draw(st.floats(-6, 6)),
                                        v + draw(st.floats(-6, 6)), draw(st.floats(3, 50)),
                                        draw(st.floats(3, 50)), draw(st.floats(-90, 90)))
    return blocks, calib, masks


def locations(draw, calib: Calibration, blocks: list[Block], n: int):
    """Fovea locations near the blocks (and some anywhere), any angle."""
    out = []
    for _ in range(n):
        b = draw(st.sampled_from(blocks))
        u, v = (float(a) for a in calib.world_to_pixel(b.x, b.y, 0.03 * b.level))
        out.append((u + draw(st.floats(-50, 50)), v + draw(st.floats(-50, 50)),
                    draw(st.floats(-math.pi, math.pi))))
    return out


def same_find(fast: FoveaScene, ref: FoveaSceneReference, state: int, action: int) -> None:
    try:
        want = ref.find(state, action)
    except NotFound as e:
        try:
            fast.find(state, action)
        except NotFound as got:
            assert str(got) == str(e)
        else:
            raise AssertionError(f"the reference finds no ({state}, {action}), the fast path does")
        return
    assert fast.find(state, action) == want


def same_features(fast: FoveaScene, ref: FoveaSceneReference, u: float, v: float, a: float):
    s1, under1, bits1 = fast.features_at(u, v, a)
    s2, under2, bits2 = ref.features_at(u, v, a)
    assert (s1, bits1) == (s2, bits2)
    assert (under1.ids if under1 else None) == (under2.ids if under2 else None)
    assert all(type(b) is bool for b in bits1)


def check_twins(data, blocks, calib, masks, params=None) -> None:
    params = params or FoveaParams()
    fast = FoveaScene(blocks, calib, params, masks=masks)
    ref = FoveaSceneReference(blocks, calib, params, masks=masks)
    for a, b in zip(fast.stacks, ref.stacks, strict=True):  # the pixels, rasterised in a box
        assert a.ids == b.ids
        np.testing.assert_array_equal(a.union, b.union)
        np.testing.assert_array_equal(a.inter, b.inter)
    assert fast.available_states() == ref.available_states()
    assert fast.observe() == ref.observe()  # instances, order, every field to the last bit
    assert fast.observe(max_height=1) == ref.observe(max_height=1)
    for _ in range(2):
        same_find(fast, ref, data.draw(st.integers(0, 4)), data.draw(st.integers(1, N_ACTIONS)))
    for u, v, a in locations(data.draw, calib, blocks, 8):
        same_features(fast, ref, u, v, a)


@settings(max_examples=40, deadline=None)
@given(scene=scenes(with_masks=False), data=st.data())
def test_the_fast_fovea_is_its_reference_on_memory_scenes(scene, data):
    check_twins(data, *scene)


@settings(max_examples=25, deadline=None)
@given(scene=scenes(with_masks=True), data=st.data(),
       window=st.sampled_from([(40, 10.0), (20, 5.0), (41, 9.5), (40, 12.5)]))
def test_the_fast_fovea_is_its_reference_with_image_masks(scene, data, window):
    check_twins(data, *scene, params=FoveaParams(size_px=window[0], offset_px=window[1]))


def test_pixels_on_the_window_edges_count_as_in_the_reference():
    """At angle 0 and whole pixels, columns of two equally tall stacks lie exactly on the
    window's edges (lx = -20 is in, lx = 20 is out): which stack is under the fovea turns on
    them."""
    calib = Calibration.overhead_default()
    red, green = (np.zeros((calib.height, calib.width), bool) for _ in range(2))
    red[230:251, 300:310] = True  # 21 rows x columns 300..309
    green[230:250, 330:341] = True  # 20 rows x columns 330..340
    blocks = [Block("red", "red", 0.2, 0.0, 0.0), Block("green", "green", 0.25, 0.1, 0.0)]
    masks = {"red": red, "green": green}
    fast = FoveaScene(blocks, calib, masks=masks)
    ref = FoveaSceneReference(blocks, calib, masks=masks)
    under = set()
    for u in np.arange(315.0, 325.5, 0.5):
        for v in (230.0, 240.0, 249.5, 250.0, 270.0):
            same_features(fast, ref, u, v, 0.0)
            under.add(ref.features_at(u, v, 0.0)[1].ids)
    assert under == {("red",), ("green",)}


def test_probe_points_on_the_hull_are_decided_as_the_reference_does(monkeypatch):
    """Angle 0 at whole and half pixels puts probe points exactly on hull edges and vertices
    of an axis-aligned square of pixels, and a three-pixel triangle has area 0.5: the kernel
    leaves these to the reference's OpenCV hull (UNSURE), and the answers agree."""
    calib = Calibration.overhead_default()
    h, w = calib.height, calib.width
    square = np.zeros((h, w), bool)
    square[230:251, 310:331] = True  # pixels 310..330 x 230..250
    triangle = np.zeros((h, w), bool)
    triangle[100, 100] = triangle[100, 101] = triangle[101, 100] = True
    blocks = [Block("red", "red", 0.2, 0.0, 0.0), Block("green", "green", 0.25, 0.1, 0.0)]
    masks = {"red": square, "green": triangle}
    fast = FoveaScene(blocks, calib, masks=masks)
    ref = FoveaSceneReference(blocks, calib, masks=masks)
    codes = []
    kernel = fovea_kernels.features_at

    def spy(*args):
        out = kernel(*args)
        codes.append(out[1])
        return out

    monkeypatch.setattr(fovea_kernels, "features_at", spy)
    for u in np.arange(300.0, 341.0, 0.5):
        for v in (230.0, 240.0, 240.5, 250.0):
            same_features(fast, ref, u, v, 0.0)
            same_features(fast, ref, u, v, math.pi / 2)
    for u, v in ((100.0, 100.0), (110.0, 110.0), (90.0, 90.0), (100.5, 100.5),
                 (100 + 1 / 3, 100 + 1 / 3)):  # the last: the centre inside the triangle
        for a in (0.0, 0.3, -1.2):
            same_features(fast, ref, u, v, a)
    assert fovea_kernels.UNSURE in codes
    assert any(c != fovea_kernels.UNSURE for c in codes)
