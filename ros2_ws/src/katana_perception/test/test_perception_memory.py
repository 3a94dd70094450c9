"""Block memory against ground truth: scripted sequences with stacking, occlusion by the arm,
falls and collapses, each rendered, segmented and folded in as the nodes would."""

import math

import numpy as np
import pytest
from katana_perception.core.calibration import Calibration
from katana_perception.core.fovea import FoveaScene, NotFound
from katana_perception.core.memory import Block, BlockMemory, Seen
from katana_perception.core.segmentation import Segmenter
from katana_perception.core.synthetic import Renderer, SceneBlock, stack_block

CALIB = Calibration.overhead_default()
H = 0.03


class World:
    """Ground truth: where every block is and what it rests on."""

    def __init__(self, poses: dict[str, tuple[float, float, float]]):
        self.blocks = {n: stack_block(n, x, y, 1, yaw) for n, (x, y, yaw) in poses.items()}
        self.support: dict[str, str | None] = dict.fromkeys(poses)
        self.renderer = Renderer(CALIB)
        self.frame = 0

    def above(self, name):
        return [n for n, s in self.support.items() if s == name]

    def top_of(self, name):
        while self.above(name):
            name = self.above(name)[0]
        return name

    def stack_of(self, top):
        chain = [top]
        while self.support[chain[-1]] is not None:
            chain.append(self.support[chain[-1]])
        return chain[::-1]

    def put_on(self, name, target, dx=0.0, dy=0.0, dyaw=0.0):
        assert not self.above(name) and name != target
        t = self.blocks[target]
        self.blocks[name] = stack_block(name, t.x + dx, t.y + dy, t.level + 1, t.yaw + dyaw)
        self.support[name] = target

    def put_table(self, name, x, y, yaw=0.0):
        assert not self.above(name)
        self.blocks[name] = stack_block(name, x, y, 1, yaw)
        self.support[name] = None

    def render(self, arm: SceneBlock | None = None):
        self.frame += 1
        scene = list(self.blocks.values()) + ([arm] if arm else [])
        return self.renderer.render(scene, seed=self.frame)[0]


def observe(memory: BlockMemory, img) -> dict:
    dets = Segmenter().segment(img, CALIB, memory.levels())
    return memory.update([Seen(d.color, d.color, d.u, d.v, d.angle, d.complete) for d in dets])


def check(memory: BlockMemory, world: World, where: str) -> None:
    assert memory.consistent(), where
    assert set(memory.blocks) == set(world.blocks), where
    for name, b in world.blocks.items():
        m = memory.blocks[name]
        assert m.level == b.level, f"{where}: {name} level {m.level}, truth {b.level}"
        assert m.support == world.support[name], f"{where}: {name} on {m.support}"
        assert m.on_top == (not world.above(name)), f"{where}: {name} on_top"
        err = math.hypot(m.x - b.x, m.y - b.y)
        assert err < 0.006, f"{where}: {name} {err * 1000:.1f} mm off"


def settle(memory, world, where, frames=2, arm=None):
    for _ in range(frames):
        observe(memory, world.render(arm))
    if arm is None:
        check(memory, world, where)


START = {"red": (0.17, 0.09, 0.1), "green": (0.26, -0.10, -0.3), "blue": (0.18, -0.07, 0.5),
         "yellow": (0.27, 0.09, 0.0), "cyan": (0.22, 0.0, 0.2)}


def test_scripted_sequence_with_occlusion_falls_and_collapse():
    world = World(START)
    memory = BlockMemory(CALIB)
    settle(memory, world, "scatter")
    assert all(b.visible and b.level == 1 for b in memory.blocks.values())

    # 1. stable: red onto green, then blue onto red (an offset, partly covering red).
    world.put_on("red", "green", 0.006, -0.004, 0.1)
    img = world.render()
    observe(memory, img)
    memory.apply_experience("red", +1, ["green"], (world.blocks["red"].x, world.blocks["red"].y))
    settle(memory, world, "red on green")
    world.put_on("blue", "red", -0.008, 0.005, -0.2)
    observe(memory, world.render())
    memory.apply_experience("blue", +1, ["green", "red"])
    settle(memory, world, "blue on red")
    assert not memory.blocks["green"].visible and memory.blocks["blue"].level == 3

    # 2. the arm hides the stack and the yellow block for a while: nothing is forgotten.
    arm = SceneBlock("red", 0.26, 0.0, 0.25, size=(0.06, 0.26, 0.04), rgb=(0.35, 0.35, 0.38))
    settle(memory, world, "arm over the stack", frames=3, arm=arm)
    assert not memory.blocks["yellow"].visible and memory.blocks["yellow"].missing > 0
    settle(memory, world, "arm gone")
    assert memory.blocks["yellow"].visible and memory.blocks["yellow"].missing == 0

    # 3. fell: cyan placed on blue slides off onto the table beside the stack.
    world.put_table("cyan", 0.205, -0.115, 0.4)
    observe(memory, world.render())
    memory.apply_experience("cyan", -1, ["green", "red", "blue"])
    settle(memory, world, "cyan fell")

    # 4. collapse: yellow placed on blue, the whole stack comes down.
    for name, (x, y, yaw) in {"blue": (0.14, -0.14, 0.1), "red": (0.29, -0.06, -0.4),
                              "green": (0.27, -0.14, 0.2), "yellow": (0.26, 0.12, 0.6)}.items():
        world.put_table(name, x, y, yaw)  # top first: each is free when it falls
    observe(memory, world.render())
    memory.apply_experience("yellow", -1, ["green", "red", "blue"])
    settle(memory, world, "collapse")
    assert all(b.level == 1 and b.on_top for b in memory.blocks.values())

    # 5. an unannounced move (no experience): the memory sees cyan now covers yellow.
    world.put_on("cyan", "yellow", 0.003, 0.003)
    settle(memory, world, "cyan onto yellow, inferred")
    # ... and the same block taken away again and put on the table.
    world.put_table("cyan", 0.16, 0.02, 0.0)
    settle(memory, world, "cyan back on the table")


def test_a_move_seen_only_in_images_lands_on_a_block_the_arm_hid_on_the_way():
    """No experience: red is carried (hidden by the arm) onto blue, and the arm hides blue for a
    frame before it lets go, so blue has gone missing by the time red appears on it. Red rests
    on blue. A block that was already gone while red still rested elsewhere takes nothing."""
    world = World(START)
    memory = BlockMemory(CALIB)
    settle(memory, world, "scatter")
    def arm_over(b):
        return SceneBlock("arm", b.x, b.y, 0.2, size=(0.07, 0.07, 0.04), rgb=(0.35, 0.35, 0.38))

    carried = world.blocks.pop("red")
    observe(memory, world.render(arm_over(carried)))  # picked: red is in the gripper
    observe(memory, world.render(arm_over(world.blocks["blue"])))  # blue hidden as well
    assert memory.blocks["blue"].missing > 0 and memory.blocks["red"].missing > 0
    world.blocks["red"] = carried
    world.put_on("red", "blue", 0.002, -0.002)
    settle(memory, world, "red on blue, seen only in images")
    assert memory.blocks["red"].level == 2 and not memory.blocks["blue"].on_top

    # yellow is taken away (no arm seen) while green still rests at its place; green is then
    # put where yellow was: yellow was gone before green moved, so green is on the table.
    yellow = world.blocks.pop("yellow")
    del world.support["yellow"]
    for _ in range(2):
        observe(memory, world.render())
    assert memory.blocks["yellow"].missing == 2 and memory.blocks["green"].visible
    world.put_table("green", yellow.x + 0.002, yellow.y, yellow.yaw)
    observe(memory, world.render())
    assert memory.blocks["green"].support is None and memory.blocks["green"].level == 1


def random_experiments(seed: int, steps: int) -> dict:
    rng = np.random.default_rng(seed)
    names = ["red", "green", "blue", "yellow", "orange", "purple"]
    spots = [(0.16, 0.10), (0.28, 0.09), (0.17, -0.09), (0.27, -0.10), (0.22, 0.0),
             (0.22, 0.13), (0.22, -0.13), (0.16, 0.0), (0.28, 0.0)]
    world = World({n: (*spots[i], float(rng.uniform(-0.7, 0.7))) for i, n in enumerate(names)})
    memory = BlockMemory(CALIB)
    settle(memory, world, f"seed {seed} start")
    counts = {"stacked": 0, "fell": 0, "collapsed": 0, "level3": 0}

    def free_spot():
        used = [(b.x, b.y) for b in world.blocks.values()]
        order = rng.permutation(len(spots))
        for k in order:
            x, y = spots[k]
            if all(math.hypot(x - a, y - b) > 0.07 for a, b in used):
                return x, y
        return None

    for step in range(steps):
        where = f"seed {seed} step {step}"
        tops = [n for n in names if not world.above(n)]
        heights = {n: world.blocks[n].level for n in tops}
        targets = [n for n in tops if heights[n] < 3]
        target = targets[int(rng.integers(len(targets)))] if targets else None
        movers = [n for n in tops if n != target and not (target and world.above(n))]
        if target is not None:
            movers = [n for n in movers if n not in world.stack_of(target)]
        if not movers:
            break
        mover = movers[int(rng.integers(len(movers)))]
        support = world.stack_of(target) if target else []
        outcome = rng.random()
        if target is None or outcome < 0.6:  # stable
            if target is None:
                spot = free_spot()
                if spot is None:
                    continue
                world.put_table(mover, *spot, float(rng.uniform(-0.7, 0.7)))
            else:
                world.put_on(mover, target, *rng.uniform(-0.008, 0.008, 2),
                             float(rng.uniform(-0.2, 0.2)))
                counts["stacked"] += 1
                counts["level3"] += world.blocks[mover].level == 3
            label = 1
        else:
            label = -1
            spot = free_spot()
            if spot is None:
                continue
            world.put_table(mover, *spot, float(rng.uniform(-0.7, 0.7)))
            counts["fell"] += 1
            if outcome > 0.85 and len(support) > 1:  # collapse: the upper part falls
                counts["collapsed"] += 1
                for name in support[1:][::-1]:
                    spot = free_spot()
                    if spot is None:
                        break
                    world.put_table(name, *spot, float(rng.uniform(-0.7, 0.7)))
        observe(memory, world.render())
        memory.apply_experience(mover, label, support)
        settle(memory, world, where)
    return counts


def test_random_experiment_sequences():
    total = {}
    for seed in range(6):
        for k, v in random_experiments(seed, steps=14).items():
            total[k] = total.get(k, 0) + v
    # the sequences did exercise what they are meant to
    assert total["stacked"] >= 20 and total["fell"] >= 10
    assert total["collapsed"] >= 2 and total["level3"] >= 3, total


def test_structure_is_repaired_and_always_consistent():
    memory = BlockMemory(CALIB)
    memory.set_blocks([Block("a", "a", 0.2, 0.0, 0.0, support="b"),
                       Block("b", "b", 0.2, 0.0, 0.0, support="a"),  # a cycle
                       Block("c", "c", 0.25, 0.05, 0.0, support="b"),  # b carries two
                       Block("d", "d", 0.15, 0.05, 0.0, support="ghost")])
    assert memory.consistent()
    assert memory.blocks["d"].support is None and memory.blocks["d"].level == 1
    carried = [b.support for b in memory.blocks.values() if b.support]
    assert len(carried) == len(set(carried))


def test_experience_for_an_unknown_block_is_ignored():
    memory = BlockMemory(CALIB)
    memory.set_blocks([Block("red", "red", 0.2, 0.0, 0.0)])
    assert "unknown" in memory.apply_experience("ghost", 1, ["red"])
    assert memory.blocks["red"].on_top and memory.consistent()


def test_forgetting_a_block_that_is_gone():
    memory = BlockMemory(CALIB)
    memory.params.forget_after = 3
    memory.set_blocks([Block("red", "red", 0.2, 0.0, 0.0), Block("blue", "blue", 0.25, 0.05, 0)])
    u, v = CALIB.world_to_pixel(0.25, 0.05, 0.03)
    seen = [Seen("blue", "blue", float(u), float(v), 0.0, True)]
    for _ in range(2):
        memory.update(seen)
    assert "red" in memory.blocks and not memory.blocks["red"].visible
    memory.update(seen)
    assert "red" not in memory.blocks


def test_a_block_that_fell_onto_its_side_is_remembered_so_and_offers_no_placement():
    """Rendered on its side, a block is remembered 40 mm tall on a 40 x 30 footprint; the
    fovea offers no placement on it; stood up again, it is a support again."""
    from katana_perception.messages import (  # noqa: PLC0415 - ROS: the other tests run without it
        blocks_from_msg,
        blocks_to_msg,
        detection_to_msg,
        seen_from_msg,
    )
    from std_msgs.msg import Header  # noqa: PLC0415 - ROS: the other tests run without it

    def look(scene):  # as perception and block_memory see it: through perception/detections
        seg = Segmenter()
        dets = seg.segment(Renderer(CALIB).render(scene, seed=1)[0], CALIB, memory.levels())
        return memory.update([seen_from_msg(detection_to_msg(d, CALIB))
                              for d in dets])

    memory = BlockMemory(CALIB)
    memory.set_blocks([Block("red", "red", 0.22, 0.06, 0.2), Block("blue", "blue", 0.2, -0.08, 0)])
    blue = stack_block("blue", 0.2, -0.08, 1, 0.0)
    assert FoveaScene(memory.snapshot(), CALIB).available_states() == [0, 1]
    look([SceneBlock("red", 0.25, 0.02, 0.02, yaw=0.3, roll=math.pi / 2), blue])
    red = memory.blocks["red"]
    assert not red.upright and red.size[2] == 0.04 and sorted(red.size[:2]) == [0.03, 0.04]
    assert math.hypot(red.x - 0.25, red.y - 0.02) < 0.003
    assert red.z == 0.02 and red.top_z == 0.04 and memory.blocks["blue"].upright
    # the long edge of the footprint runs along the block's yaw (0.3) or across it
    long_yaw = red.yaw if red.size[0] > red.size[1] else red.yaw + math.pi / 2
    assert abs(math.sin(long_yaw - 0.3)) < 0.05
    # the fovea sees it as an obstacle, not as a stack to place on
    again = blocks_from_msg(blocks_to_msg(memory.snapshot(), Header()))
    assert [b.size for b in again] == [b.size for b in memory.snapshot()]
    fovea = FoveaScene(again, CALIB)
    placements = fovea.observe()
    assert all(i.support_ids != ("red",) for i in placements)
    assert {i.support_ids for i in placements if i.state == 1} == {("blue",)}
    with pytest.raises(NotFound):
        FoveaScene([b for b in again if b.id == "red"], CALIB).find(1, 6)
    # stood up again where it lay: upright, and a support
    look([stack_block("red", 0.25, 0.02, 1, 0.3), blue])
    assert memory.blocks["red"].upright and memory.blocks["red"].size == (0.04, 0.04, 0.03)
    assert ("red",) in {i.support_ids for i in FoveaScene(memory.snapshot(), CALIB).observe()}


def test_a_block_that_came_to_rest_partly_covered_has_an_unknown_resting_pose():
    """Its top face not in full view, a block that moved may lie on its side unnoticed: its
    resting pose is known again only from a clean view (the loop picked such a block, on its
    side, and placed it on its side: a 'fall' the paper's world does not have)."""

    def seen(name, x, y, complete, z=H):
        u, v = CALIB.world_to_pixel(x, y, z)
        return Seen(name, name, float(u), float(v), 0.0, complete)

    memory = BlockMemory(CALIB)
    memory.update([seen("red", 0.2, 0.0, True), seen("blue", 0.2, 0.1, False)])
    assert memory.blocks["red"].pose_known and not memory.blocks["blue"].pose_known
    memory.update([seen("red", 0.2, 0.0, True), seen("blue", 0.2, 0.1, True)])
    assert memory.blocks["blue"].pose_known  # a clean view
    memory.update([seen("red", 0.25, -0.05, False), seen("blue", 0.2, 0.1, True)])
    assert not memory.blocks["red"].pose_known  # moved, and came to rest partly covered
    memory.update([seen("red", 0.25, -0.05, False), seen("blue", 0.2, 0.1, False)])
    assert not memory.blocks["red"].pose_known and memory.blocks["blue"].pose_known  # blue stayed
    memory.update([seen("red", 0.25, -0.05, True), seen("blue", 0.2, 0.1, True)])
    assert memory.blocks["red"].pose_known
