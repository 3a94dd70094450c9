"""Fovea features against a brute-force geometric computation, and the scan/search rules."""

import math

import cv2
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from katana_perception.core.calibration import Calibration, default_camera_matrix
from katana_perception.core.colors import NOMINAL_RGB
from katana_perception.core.fovea import (
    N_ACTIONS,
    FoveaParams,
    FoveaScene,
    FoveaSceneReference,
    NotFound,
    action_of,
    feature_vector,
)
from katana_perception.core.memory import Block
from katana_perception.core.synthetic import random_scene
from scipy.spatial import ConvexHull, QhullError

CALIB = Calibration.overhead_default()
H, W = CALIB.height, CALIB.width
NAMES = list(NOMINAL_RGB)


def rect_mask(u, v, w, h, angle_deg):
    m = np.zeros((H, W), np.uint8)
    box = cv2.boxPoints(((u, v), (w, h), angle_deg))
    cv2.fillPoly(m, [np.rint(box).astype(np.int32)], 1)
    return m.astype(bool)


@st.composite
def mask_scenes(draw):
    """1-2 stacks of 1-3 blocks given as pixel masks (rotated rectangles), plus a fovea."""
    blocks, masks, stacks = [], {}, []
    n_stacks = draw(st.integers(1, 2))
    u0 = draw(st.floats(150, 490))
    for s in range(n_stacks):
        u = u0 if s == 0 else u0 + draw(st.sampled_from([-1, 1])) * draw(st.floats(25, 60))
        v = draw(st.floats(150, 330))
        height = draw(st.integers(1, 3))
        ids = []
        for level in range(1, height + 1):
            bid = NAMES[len(blocks)]
            du, dv = (0.0, 0.0) if level == 1 else (draw(st.floats(-12, 12)),
                                                   draw(st.floats(-12, 12)))
            w_, h_ = draw(st.floats(25, 50)), draw(st.floats(25, 50))
            masks[bid] = rect_mask(u + du, v + dv, w_, h_, draw(st.floats(-90, 90)))
            x, y = CALIB.pixel_to_world(u, v, 0.03 * level)
            blocks.append(Block(bid, bid, float(x), float(y), 0.0,
                                support=ids[-1] if ids else None))
            ids.append(bid)
        stacks.append(ids)
    fu = u0 + draw(st.floats(-45, 45))
    fv = draw(st.floats(120, 360))
    angle = draw(st.floats(-math.pi / 4, math.pi / 4))
    return blocks, masks, stacks, (fu, fv, angle)


def brute_force(masks, stacks, fu, fv, angle, size=40, r=10.0):
    """Per-definition: pixels whose fovea-frame coordinates fall in [-20, 20)^2; the state is
    the tallest stack with such pixels; its blocks' masks are intersected; qhull gives the
    hull in image coordinates; the five points are mapped into the image and tested against
    the hull's half-planes. Returns (state, bits, smallest |distance| to the hull)."""
    ys, xs = np.mgrid[0:H, 0:W]
    dx, dy = xs - fu, ys - fv
    lx = dx * math.cos(angle) + dy * math.sin(angle)
    ly = -dx * math.sin(angle) + dy * math.cos(angle)
    window = (lx >= -size / 2) & (lx < size / 2) & (ly >= -size / 2) & (ly < size / 2)
    best = None
    for ids in stacks:
        union = np.zeros((H, W), bool)
        for b in ids:
            union |= masks[b]
        n = int((union & window).sum())
        if n and (best is None or (len(ids), n) > (len(best[0]), best[1])):
            best = (ids, n)
    if best is None:
        return 0, (False,) * 5, math.inf
    inter = np.ones((H, W), bool)
    for b in best[0]:
        inter &= masks[b]
    py, px = np.nonzero(inter & window)
    pts = np.column_stack([px, py]).astype(float)
    probes = [(0, 0), (-r, -r), (r, -r), (r, r), (-r, r)]
    img_pts = [(fu + a * math.cos(angle) - b * math.sin(angle),
                fv + a * math.sin(angle) + b * math.cos(angle)) for a, b in probes]
    try:
        hull = ConvexHull(pts)
    except (QhullError, ValueError):
        return len(best[0]), (False,) * 5, math.inf
    dist = [float(np.max(hull.equations[:, :2] @ p + hull.equations[:, 2])) for p in img_pts]
    return len(best[0]), tuple(d <= 0 for d in dist), min(abs(d) for d in dist)


@settings(max_examples=120, deadline=None)
@given(mask_scenes())
def test_features_match_brute_force(scene):
    blocks, masks, stacks, (fu, fv, angle) = scene
    fovea = FoveaScene(blocks, CALIB, FoveaParams(), masks=masks)
    state, under, bits = fovea.features_at(fu, fv, angle)
    want_state, want_bits, margin = brute_force(masks, stacks, fu, fv, angle)
    assume(margin > 1e-6)  # a point exactly on the hull edge: either answer is right
    assert state == want_state
    assert bits == want_bits
    assert (under is None) == (state == 0)
    if under is not None:
        assert list(under.ids) in stacks


def test_action_and_features():
    assert action_of([False] * 5) == 1 and action_of([True] * 5) == 6
    for a in range(1, N_ACTIONS + 1):
        x = feature_vector(a)
        assert len(x) == 7 and x[-1] == 1.0 and x[a - 1] == 1.0 and sum(x) == 2.0
    with pytest.raises(ValueError):
        feature_vector(7)


def memory_scene(seed: int, n: int = 4, max_height: int = 3) -> list[Block]:
    rng = np.random.default_rng(seed)
    scene = random_scene(rng, NAMES[:n], max_height=max_height, max_offset=0.006)
    out, prev = [], None
    for b in scene:
        sup = prev.name if prev is not None and b.level == prev.level + 1 else None
        out.append(Block(b.name, b.name, b.x, b.y, b.yaw, support=sup, level=b.level))
        prev = b
    return out


@pytest.mark.parametrize("seed", range(12))
def test_observe_instances_are_consistent(seed):
    blocks = memory_scene(seed)
    fovea = FoveaScene(blocks, CALIB)
    insts = fovea.observe()
    assert insts and insts[0].state == 0 and insts[0].action == 1
    states = [i.state for i in insts]
    assert states == sorted(states)
    seen = set()
    h = 0.03
    for i in insts:
        key = (i.state, i.action, i.support_ids)
        assert key not in seen  # every distinct pair once per stack
        seen.add(key)
        s, under, bits = fovea.features_at(i.u, i.v, i.angle)
        assert (s, bits) == (i.state, i.bits) and i.action == action_of(bits)
        assert i.features == feature_vector(i.action)
        assert (under.ids if under else ()) == i.support_ids
        assert len(i.support_ids) == i.state
        u, v = CALIB.world_to_pixel(i.x, i.y, i.state * h)
        assert abs(float(u) - i.u) < 1e-6 and abs(float(v) - i.v) < 1e-6
        assert i.z == pytest.approx(i.state * h + h / 2)
        assert 0.14 <= math.hypot(i.x, i.y) <= 0.29
        if i.support_ids:
            top = next(b for b in blocks if b.id == i.support_ids[-1])
            assert i.yaw == pytest.approx((top.yaw + math.pi / 4) % (math.pi / 2) - math.pi / 4)
    # Every stack of an allowed height offers its centre placement: all five bits on.
    for ids in {i.support_ids for i in insts if i.state > 0}:
        assert any(i.action == 6 for i in insts if i.support_ids == ids)


@pytest.mark.parametrize("seed", range(8))
def test_find_placement_realises_the_pair_and_agrees_with_observe(seed):
    blocks = memory_scene(seed)
    fovea = FoveaScene(blocks, CALIB)
    insts = fovea.observe()
    first = {}
    for i in insts:
        first.setdefault((i.state, i.action), i)
    for (s, a), want in first.items():
        got = fovea.find(s, a)
        assert (got.state, got.action) == (s, a)
        assert (got.u, got.v, got.support_ids) == (want.u, want.v, want.support_ids)
    # A pair the coarse grid misses may still be found by the finer pass; any answer must
    # really realise the pair.
    for s in fovea.available_states():
        for a in range(1, N_ACTIONS + 1):
            try:
                got = fovea.find(s, a)
            except NotFound:
                continue
            st_, _, bits = fovea.features_at(got.u, got.v, got.angle)
            assert (st_, action_of(bits)) == (s, a)


def _realisable_actions(fovea: FoveaScene, stack) -> set[int]:
    """Brute force: every action a reachable, clear placement realises on `stack` at any point
    of the grid or the fine grid (the two `find` searches)."""
    actions = set()
    for step in (fovea.params.grid_step_px, fovea.params.fine_step_px):
        for u, v, ang in fovea._around(stack, step):
            if not fovea._in_image(u, v):
                continue
            state, under, bits = fovea.features_at(u, v, ang)
            if under is stack and fovea._instance(state, bits, u, v, ang, stack) is not None:
                actions.add(action_of(bits))
    return actions


def test_observe_offers_every_action_the_arm_can_make_on_a_stack():
    """What observe offers on each stack is what a search of both grids realises there, so a
    plan never builds towards a pair the offer would hide. Stacks of 2-3 blocks, each turned
    and shifted a little from the one below, as the arm leaves them."""
    rng = np.random.default_rng(7)
    fine_only = 0
    for _ in range(40):
        x, y, yaw = rng.uniform(0.18, 0.24), rng.uniform(-0.1, 0.1), rng.uniform(-0.7, 0.7)
        blocks, below = [], None
        for level in range(1, int(rng.integers(2, 4)) + 1):
            if level > 1:
                x, y = x + rng.normal(0, 0.003), y + rng.normal(0, 0.003)
                yaw += rng.normal(0, 0.05)
            blocks.append(Block(NAMES[level], NAMES[level], x, y, yaw, support=below,
                                level=level))
            below = NAMES[level]
        fovea = FoveaScene(blocks, CALIB)
        offered = {i.action for i in fovea.observe() if i.state > 0}
        (stack,) = fovea.stacks
        assert offered == _realisable_actions(fovea, stack)
        coarse = {i.action for i in fovea._stack_instances(stack, fovea.params.grid_step_px)}
        fine_only += bool(offered - coarse)
    assert fine_only > 0  # the sample holds stacks whose grid alone misses an action


def test_find_placement_explains_what_cannot_be_done():
    blocks = [Block("red", "red", 0.2, 0.05, 0.0), Block("green", "green", 0.25, -0.08, 0.1),
              Block("blue", "blue", 0.25, -0.08, 0.1, support="green")]
    fovea = FoveaScene(blocks, CALIB)
    assert fovea.available_states() == [0, 1, 2]
    with pytest.raises(NotFound, match="no stack of height 3"):
        fovea.find(3, 1)
    with pytest.raises(NotFound, match="above the highest allowed"):
        fovea.find(9, 1)
    with pytest.raises(NotFound, match="action 7 does not exist"):
        fovea.find(1, 7)
    with pytest.raises(NotFound, match="only action 1"):
        fovea.find(0, 3)
    assert fovea.find(2, 6).support_ids == ("green", "blue")


def test_placements_are_reachable_and_clear_of_neighbours():
    # Two stacks so close that placing beside one would hit the other.
    blocks = [Block("red", "red", 0.22, 0.0, 0.0), Block("green", "green", 0.22, 0.047, 0.0),
              Block("blue", "blue", 0.22, 0.047, 0.0, support="green")]
    fovea = FoveaScene(blocks, CALIB)
    for i in fovea.observe():
        for b in blocks:
            if b.id in i.support_ids:
                continue
            # centre distance along y: a placed block and a neighbour must not overlap
            assert abs(i.y - b.y) >= 0.04 + 0.005 - 1e-6 or abs(i.x - b.x) >= 0.045 - 1e-6
    far = [Block("red", "red", 0.05, 0.0, 0.0)]  # only out of reach
    with pytest.raises(NotFound):
        FoveaScene(far, CALIB).find(1, 6)


def test_reach_shrinks_with_stack_height():
    # a stack of two centred at 0.27 m: its top spans 0.25..0.29 m, beyond the 0.25 m limit
    # for placing on height 2 except at its near edge
    blocks = [Block("red", "red", 0.27, 0.0, 0.0),
              Block("green", "green", 0.27, 0.0, 0.0, support="red"),
              Block("blue", "blue", 0.18, 0.06, 0.0)]
    limits = (0.30, 0.28, 0.25, 0.20)
    bands = tuple((0.14, far) for far in limits)
    fovea = FoveaScene(blocks, CALIB, FoveaParams(reach_by_height=bands))
    instances = fovea.observe()
    assert {0, 1} <= {i.state for i in instances}
    for i in instances:
        assert math.hypot(i.x, i.y) <= limits[min(i.state, 3)] + 1e-9
    with pytest.raises(NotFound):
        fovea.find(2, 6)  # all five points on the top need the centre beyond 0.26 m
    # without the per-height limits the same placement is offered
    assert FoveaScene(blocks, CALIB, FoveaParams()).find(2, 6).state == 2


def test_table_instance_needs_a_free_place():
    blocks = memory_scene(3)
    fovea = FoveaScene(blocks, CALIB)
    t = fovea.find(0, 1)
    state, under, bits = fovea.features_at(t.u, t.v, t.angle)
    assert state == 0 and under is None and not any(bits)
    # A play area whose only grid place is taken by a block: nowhere to put one down.
    only = FoveaParams(area_x=(0.2, 0.2001), area_y=(0.0, 0.0001))
    taken = [Block("red", "red", 0.21, 0.01, 0.3)]
    with pytest.raises(NotFound, match="free"):
        FoveaScene(taken, CALIB, only).find(0, 1)
    free = FoveaScene([Block("red", "red", 0.27, 0.1, 0.3)], CALIB, only).find(0, 1)
    assert free.x == pytest.approx(0.2) and free.y == pytest.approx(0.0)


def test_invalid_parameters_are_refused():
    with pytest.raises(ValueError, match="offset_px"):
        FoveaScene([], CALIB, FoveaParams(offset_px=25))


@settings(max_examples=25, deadline=None)
@given(x=st.floats(0.16, 0.28), y=st.floats(-0.1, 0.1), yaw=st.floats(-0.78, 0.78))
def test_on_a_single_block_the_fovea_never_realises_action_5(x, y, yaw):
    """The learner's feasibility table (katana_curiosity robot_loop.feasible_actions) rules out
    action 5 on one block: the fovea turns with the block, and an aligned rectangle holding
    three corners of the probe square holds the fourth. The fovea's own search agrees (pixel
    rounding could break it only along a one-pixel line)."""
    fovea = FoveaScene([Block("red", "red", x, y, yaw)], CALIB)
    with pytest.raises(NotFound):
        fovea.find(1, 5)
    for action in (1, 2, 3, 4, 6):  # the search does reach every other action
        assert fovea.find(1, action).action == action


@pytest.mark.filterwarnings("error::RuntimeWarning")  # no pixel cast out of range
@pytest.mark.parametrize("D", [None, [0.2, -0.2, 0.0, 0.0, 0.1]], ids=["pinhole", "distorted"])
def test_faces_far_outside_the_view_are_drawn_as_they_fall_on_the_image(D):
    """A face projected beyond what a mask can be drawn at is clipped first (a huge block over
    the table covers the whole image, as without clipping); one projected to no finite or
    plausible pixel covers none; the blocks in view are unchanged."""
    calib = CALIB if D is None else Calibration.from_camera_rpy(
        default_camera_matrix(), (0.22, 0, 0.75), (math.pi, 0, -math.pi / 2), D=D)
    near = Block("near", "blue", 0.25, -0.05, 0.1, size=(0.04, 0.04, 0.03))
    alone = FoveaScene(blocks=[near], calibration=calib).stacks[0].union

    def union_sizes(far: Block) -> list[list[int]]:
        return [[len(s.union) for s in scene(blocks=[far, near], calibration=calib).stacks]
                for scene in (FoveaScene, FoveaSceneReference)]

    for far in (Block("far", "red", 1e12, 0.05, 0.3), Block("far", "red", 9.0, 0.05, 0.3)):
        assert union_sizes(far) == [[0, len(alone)]] * 2
    huge = Block("far", "red", 0.2, 0.05, 0.3, size=(1e9, 1e9, 0.03))
    sizes = union_sizes(huge)
    assert sizes[0] == sizes[1]
    if D is None:  # the pinhole's rays all fall on the huge block's top
        assert sizes[0] == [H * W, len(alone)]
