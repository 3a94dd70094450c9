"""The outcome judge against ground truth over scripted placements (synthetic renders) and
physics placements (PyBullet): 98% or more correct."""

import math
from collections import Counter

import katana_sim.core as sim
import numpy as np
from katana_perception.core.calibration import Calibration
from katana_perception.core.judge import FELL, STABLE, Judge, Placement
from katana_perception.core.memory import Block
from katana_perception.core.segmentation import Segmenter
from katana_perception.core.synthetic import Renderer, SceneBlock, stack_block

CALIB = Calibration.overhead_default()
H = 0.03
NAMES = ["red", "green", "blue", "yellow", "orange", "purple"]
SPOTS = [(0.16, 0.11), (0.28, 0.10), (0.17, -0.10), (0.27, -0.11), (0.22, 0.0), (0.22, 0.14),
         (0.22, -0.14), (0.155, 0.0), (0.285, 0.0)]
KINDS = ("stable", "slid_off", "collapse", "support_pushed", "support_slid", "leaning", "gone",
         "on_its_side")


def memory_of(scene: list[SceneBlock], supports: dict) -> list[Block]:
    return [Block(b.name, b.name, b.x, b.y, b.yaw, support=supports[b.name], level=b.level,
                  on_top=b.name not in supports.values()) for b in scene]


def trial(seed: int, kind: str):
    """One placement: the scene before, the scene after, and the true label."""
    rng = np.random.default_rng(seed)
    spots = [SPOTS[i] for i in rng.permutation(len(SPOTS))]
    s = int(rng.integers(0, 4)) if kind in ("stable", "slid_off", "gone") else \
        int(rng.integers(1, 4))
    names = list(rng.permutation(NAMES))
    stack = names[:s]
    mover = names[s]
    others = names[s + 1: s + 3]
    before: list[SceneBlock] = []
    supports: dict[str, str | None] = {}
    sx, sy = spots[0]
    yaw = float(rng.uniform(-0.7, 0.7))
    for lv, n in enumerate(stack, start=1):
        off = rng.uniform(-0.005, 0.005, 2) if lv > 1 else (0.0, 0.0)
        sx, sy = sx + off[0], sy + off[1]
        before.append(stack_block(n, sx, sy, lv, yaw + float(rng.uniform(-0.1, 0.1))))
        supports[n] = stack[lv - 2] if lv > 1 else None
    mx, my = spots[1]
    before.append(stack_block(mover, mx, my, 1, float(rng.uniform(-0.7, 0.7))))
    supports[mover] = None
    for n, (x, y) in zip(others, spots[2:4], strict=True):
        before.append(stack_block(n, x, y, 1, float(rng.uniform(-0.7, 0.7))))
        supports[n] = None
    if s:
        top = before[s - 1]
        px, py = top.x + rng.uniform(-0.01, 0.01), top.y + rng.uniform(-0.01, 0.01)
        pyaw = top.yaw
    else:
        (px, py), pyaw = spots[4], 0.0
    after = [b for b in before if b.name != mover]
    free = spots[5:]
    label = FELL
    if kind == "stable":
        jx, jy = rng.uniform(-0.003, 0.003, 2)
        after.append(stack_block(mover, px + jx, py + jy, s + 1,
                                 pyaw + float(rng.uniform(-0.08, 0.08))))
        label = STABLE
    elif kind == "slid_off":  # landed on the table beside the stack / away from the spot
        ang = rng.uniform(0, 2 * math.pi)
        d = rng.uniform(0.055, 0.07)
        after.append(stack_block(mover, px + d * math.cos(ang), py + d * math.sin(ang), 1,
                                 float(rng.uniform(-0.7, 0.7))))
    elif kind == "collapse":  # the stack above its bottom block and the mover hit the table
        fallen = stack[1:] + [mover]
        after = [b for b in after if b.name not in fallen]
        for n, (x, y) in zip(fallen, free, strict=False):
            after.append(stack_block(n, x, y, 1, float(rng.uniform(-0.7, 0.7))))
        if s == 1:  # a single block cannot collapse: it is pushed away instead
            after = [b for b in after if b.name != stack[0]]
            after.append(stack_block(stack[0], before[0].x + 0.02, before[0].y - 0.015, 1,
                                     before[0].yaw + 0.3))
    elif kind == "support_pushed":  # the mover stays on top, but pushed its support along
        push = rng.uniform(0.015, 0.025) * np.array([math.cos(yaw), math.sin(yaw)])
        moved = {stack[-1]}
        after = [stack_block(b.name, b.x + push[0], b.y + push[1], b.level, b.yaw)
                 if b.name in moved else b for b in after]
        after.append(stack_block(mover, px + push[0], py + push[1], s + 1, pyaw))
    elif kind == "support_slid":  # the mover is on the spot, the block under it slid out
        ang = float(rng.uniform(0, 2 * math.pi))
        d = float(rng.uniform(0.015, 0.02))
        t = before[s - 1]
        after = [b for b in after if b.name != t.name]
        after.append(stack_block(t.name, t.x + d * math.cos(ang), t.y + d * math.sin(ang),
                                 t.level, t.yaw + 0.2))
        after.append(stack_block(mover, px, py, s + 1, pyaw))
    elif kind == "leaning":  # half on the stack, half off, tilted
        ang = float(rng.uniform(0, 2 * math.pi))
        d = 0.03
        after.append(SceneBlock(mover, px + d * math.cos(ang), py + d * math.sin(ang),
                                s * H + 0.005, yaw=ang, pitch=0.45))
    elif kind == "gone":  # fell off the table, out of view
        pass
    elif kind == "on_its_side":  # on the spot, but tipped over onto the stack: it stands
        # 40 mm tall where an upright block stands 30 (its top face 40 x 30, not square)
        after.append(SceneBlock(mover, px, py, s * H + 0.02, yaw=pyaw, roll=math.pi / 2))
    return before, supports, after, mover, Placement(s, px, py, tuple(stack)), label


def run_trials(n_per_kind: int, seed0: int):
    judge = Judge(Segmenter(), CALIB)
    renderer = Renderer(CALIB)
    results = Counter()
    wrong = []
    for kind in KINDS:
        for k in range(n_per_kind):
            seed = seed0 + 1000 * KINDS.index(kind) + k
            before, supports, after, mover, placement, truth = trial(seed, kind)
            img0, _ = renderer.render(before, seed=seed)
            img1, _ = renderer.render(after, seed=seed + 1)
            snap = judge.snapshot(img0, memory_of(before, supports))
            verdict = judge.judge(snap, img1, mover, placement)
            ok = verdict.label == truth
            results[(kind, ok)] += 1
            if not ok:
                wrong.append((kind, seed, verdict.reason))
    return results, wrong


def test_judge_on_scripted_placements():
    results, wrong = run_trials(n_per_kind=25, seed0=0)
    total = sum(results.values())
    correct = sum(v for (kind, ok), v in results.items() if ok)
    assert total >= 100
    assert correct / total >= 0.98, wrong
    stable_ok = results[("stable", True)]
    assert stable_ok >= 24  # it is not just saying "fell"


def physics_trial(world, rng, seed: int):
    world.reset(seed=seed)
    ids = list(world.blocks)
    s = int(rng.integers(0, 4))
    for i in range(1, s):
        world.stack(ids[i], on=ids[i - 1], dx=float(rng.uniform(-0.004, 0.004)),
                    dy=float(rng.uniform(-0.004, 0.004)))
    world.settle()
    truth0 = {b.id: b for b in world.ground_truth()}
    stack = ids[:s]
    mover = ids[s]
    if s:
        top = truth0[stack[-1]]
        r = float(rng.uniform(0.0, 0.032))
        a = float(rng.uniform(0, 2 * math.pi))
        px, py = top.position[0] + r * math.cos(a), top.position[1] + r * math.sin(a)
        yaw = top.yaw
    else:
        px, py, yaw = 0.22, 0.0, 0.0
        for b in truth0.values():
            if b.id != mover and math.hypot(b.position[0] - px, b.position[1] - py) < 0.06:
                world.set_block_pose(b.id, (0.30, 0.0, 0.015))  # clear the spot
        world.settle()
        truth0 = {b.id: b for b in world.ground_truth()}
    memory = [Block(b.id, b.id, b.position[0], b.position[1], b.yaw, level=b.level,
                    support=b.support or None) for b in truth0.values()]
    img0 = world.render()
    world.set_block_pose(mover, (px, py, s * H + H / 2 + 0.002), yaw)
    world.settle()
    truth1 = {b.id: b for b in world.ground_truth()}
    m = truth1[mover]
    stayed = all(math.hypot(truth1[i].position[0] - truth0[i].position[0],
                            truth1[i].position[1] - truth0[i].position[1]) < 0.01
                 and truth1[i].level == truth0[i].level for i in stack)
    label = STABLE if (m.level == s + 1 and not m.tilted and stayed
                       and (not s or m.support == stack[-1])) else FELL
    return img0, world.render(), memory, mover, Placement(s, px, py, tuple(stack)), label


def test_judge_on_pybullet_placements():
    world = sim.PhysicsSim(sim.SimConfig(num_blocks=6, seed=0))
    cam = world.camera
    calib = Calibration.from_camera_rpy(cam.K, cam.position, cam.rpy, cam.width, cam.height)
    judge = Judge(Segmenter(), calib)
    rng = np.random.default_rng(11)
    counts, wrong = Counter(), []
    try:
        for k in range(40):
            img0, img1, memory, mover, placement, truth = physics_trial(world, rng, 500 + k)
            verdict = judge.judge(judge.snapshot(img0, memory), img1, mover, placement)
            counts[truth] += 1
            if verdict.label != truth:
                wrong.append((k, truth, verdict.reason))
    finally:
        world.close()
    assert counts[STABLE] >= 8 and counts[FELL] >= 8, counts  # both outcomes occurred
    assert len(wrong) <= 40 * 0.02, wrong
