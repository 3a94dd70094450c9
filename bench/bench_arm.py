"""The arm's precision and speed: pick-and-places through the `pick_and_place` action on the fast
sim (sim_node + pick_place_executor in one process, real_time_factor 0), picks and places drawn
at random over the reach envelope of each height (katana_manipulation.core.reach), onto the
table and onto stacks of 1-3. `run()` returns the figures; bench/run.py writes
bench/results/arm.json.

    python bench/run.py arm

Each trial sets the scene by teleporting blocks (set-up, not measured): a stack of `height`
blocks at a random place of that height's envelope, the block to move on the table at a random
place of the pick envelope (near the base included), the other blocks out of the way. The goal
puts the block on the stack's top centre, offset by up to 5 mm and turned to a random yaw: an
action-6 placement (all five fovea points on the block below). Figures:

- `pick_success`: fraction of goals that succeeded (picked, carried, released, parked).
- `placement_error_mm`: horizontal distance of the placed block's centre from the commanded
  centre, from the sim's ground truth, over placements that stayed on their support.
- `action6_stable`: per height 1-3, the fraction of those placements that stayed (level h + 1,
  the stack below intact), one second of simulated time after the action ended.
- `pick_place_s`: median wall seconds per action; `physics_only_s`: the same motions stepped in
  PhysicsSim without ROS (tests/physics_port.py, the floor), each run just before its ROS twin
  so that both see the same load; `overhead_ratio` their quotient; `sim_s_per_pick_place` the
  simulated seconds one takes.
"""

from __future__ import annotations

import json
import math
import os
import statistics
import sys
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
from geometry_msgs.msg import Pose
from katana_bringup.in_process import InProcessGraph
from katana_common.action_client import ActionClient
from katana_description import models as m
from katana_interfaces.action import PickAndPlace
from katana_manipulation.core import pick_place as pp
from katana_manipulation.core.pick_place import PickPlaceRequest
from katana_manipulation.core.pick_place_types import SIM_MIN_SEGMENT_TIME_S
from katana_manipulation.core.reach import pick_reach, place_reach
from katana_manipulation.pick_place_executor import PickPlaceExecutor
from katana_sim.core import PhysicsSim, SimConfig
from katana_sim.sim_node import SimNode
from rclpy.parameter import Parameter

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from physics_port import PhysicsPort  # noqa: E402  (tests/ is put on the path just above)

RUNS = 64
SEED = 0
#: centre of a block next to the arm's base (radius 0.06 m) must stay this far from the axis
BASE_CLEARANCE_M = 0.06 + 0.5 * math.hypot(0.04, 0.04) + 0.008
MAX_OFFSET_M = 0.005
ANGLE_RANGE = (-math.pi / 2, math.pi / 2)  # in front of the arm, over the table and camera
OUT_OF_THE_WAY = [(0.45, 0.30), (0.45, -0.30), (0.55, 0.0), (-0.30, 0.35)]


class Trial(NamedTuple):
    world_seed: int
    height: int  # stack height to place onto (0: the table)
    stack_xy: tuple[float, float]
    stack_yaw: float
    pick_xy: tuple[float, float]
    pick_yaw: float
    offset: tuple[float, float]
    place_yaw: float


def _sample_xy(rng, band, margin_m: float = 0.0) -> tuple[float, float]:
    """Uniform over the annulus of `band`, `margin_m` inside both of its edges."""
    lo, hi = max(band.min_m, BASE_CLEARANCE_M) + margin_m, band.max_m - margin_m
    r = math.sqrt(rng.uniform(lo * lo, hi * hi))
    a = rng.uniform(*ANGLE_RANGE)
    return r * math.cos(a), r * math.sin(a)


def trials(n: int = RUNS, seed: int = SEED) -> list[Trial]:
    """Seeded trials, heights 0..3 in turn."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        h = i % 4
        while True:
            stack = _sample_xy(rng, place_reach(h), MAX_OFFSET_M)  # the offset stays inside
            pick = _sample_xy(rng, pick_reach(1))
            if math.dist(stack, pick) > 0.09:  # the fingers must not touch the stack
                break
        r = rng.uniform(0, MAX_OFFSET_M)
        a = rng.uniform(-math.pi, math.pi)
        out.append(Trial(int(rng.integers(0, 2**31 - 1)), h, stack,
                         float(rng.uniform(-math.pi / 4, math.pi / 4)), pick,
                         float(rng.uniform(-math.pi / 4, math.pi / 4)),
                         (r * math.cos(a), r * math.sin(a)), float(rng.uniform(-math.pi, math.pi))))
    return out


def set_scene(sim, trial: Trial):
    """Teleport the blocks for `trial` and let them settle; returns the PickPlaceRequest."""
    sim.reset(trial.world_seed)
    ids = list(sim.blocks)
    size = sim.cfg.block_size
    h = size[2]
    mover, stack = ids[0], ids[1:1 + trial.height]
    spare = ids[1 + trial.height:]
    for k, bid in enumerate(stack):
        sim.set_block_pose(bid, (*trial.stack_xy, h * (k + 0.5)), trial.stack_yaw)
    for bid, xy in zip(spare, OUT_OF_THE_WAY, strict=False):
        sim.set_block_pose(bid, (*xy, h / 2), 0.0)
    sim.set_block_pose(mover, (*trial.pick_xy, h / 2), trial.pick_yaw)
    sim.set_arm_positions(m.PARK_POSE, m.GRIPPER_OPEN)
    sim.settle()
    pos, _ = sim.block_pose(mover)
    truth = {b.id: b for b in sim.ground_truth()}
    place = (trial.stack_xy[0] + trial.offset[0], trial.stack_xy[1] + trial.offset[1],
             h * (trial.height + 0.5))
    return PickPlaceRequest(tuple(pos), truth[mover].yaw, size, place, trial.place_yaw), mover


def judge(sim, trial: Trial, mover: str, place) -> dict:
    """Where the moved block ended (after one more simulated second), from the ground truth."""
    sim.settle(max_time=1.0, min_time=1.0)
    truth = {b.id: b for b in sim.ground_truth()}
    b = truth[mover]
    stack = list(sim.blocks)[1:1 + trial.height]
    stack_ok = all(truth[s].level == k + 1 for k, s in enumerate(stack))
    stayed = b.level == trial.height + 1 and stack_ok and not b.tilted
    err = math.hypot(b.position[0] - place[0], b.position[1] - place[1]) * 1000.0
    return {"stayed": stayed, "error_mm": err}


class PhysicsOnly:
    """The floor: the same trials' motions stepped in a PhysicsSim without ROS."""

    def __init__(self) -> None:
        self.sim = PhysicsSim(SimConfig(seed=SEED))
        self.port = PhysicsPort(self.sim)
        # the executor's setting on the sim (as in through_ros and sim.yaml), so that both
        # paths run the same motions
        self.planner = pp.PickPlacePlanner(
            params=pp.PickPlaceParams(min_segment_time=SIM_MIN_SEGMENT_TIME_S))

    def __call__(self, trial: Trial) -> tuple[dict, float]:
        req, mover = set_scene(self.sim, trial)
        self.port.commanded = None
        t0, s0 = time.perf_counter(), self.sim.time
        res = pp.execute_pick_place(req, self.port, self.planner)
        wall = time.perf_counter() - t0
        out = {"height": trial.height, "success": res.success, "code": res.code,
               "message": res.message, "sim_s": self.sim.time - s0}
        if res.success:
            out.update(judge(self.sim, trial, mover, req.place))
        return out, wall

    def close(self) -> None:
        self.sim.close()


def physics_only(all_trials: list[Trial]) -> tuple[list[dict], list[float]]:
    floor = PhysicsOnly()
    try:
        runs = [floor(t) for t in all_trials]
    finally:
        floor.close()
    return [r[0] for r in runs], [r[1] for r in runs]


def through_ros(all_trials: list[Trial], floor=None) -> tuple[list[dict], list[float], list]:
    """Each trial through the action; `floor(trial)`, when given, runs just before each one, so
    that both see the same machine load (a shared 2-core machine)."""
    def pose(xyz, yaw) -> Pose:
        p = Pose()
        p.position.x, p.position.y, p.position.z = (float(v) for v in xyz)
        p.orientation.z, p.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
        return p

    def parked(joints) -> bool:  # the executor has seen the arm at the park pose
        return joints is not None and all(
            abs(joints[n] - q) < 1e-3 for n, q in zip(m.ARM_JOINTS, m.PARK_POSE, strict=True))

    outcomes, walls, floors = [], [], []
    with InProcessGraph() as g:
        sim = SimNode(context=g.context, parameter_overrides=[
            Parameter("real_time_factor", value=0.0), Parameter("seed", value=SEED),
            Parameter("use_sim_time", value=True)])
        executor = PickPlaceExecutor(context=g.context, parameter_overrides=[  # as sim.yaml
            Parameter("use_sim_time", value=True),
            Parameter("min_segment_time_s", value=SIM_MIN_SEGMENT_TIME_S)])
        g.add(sim, executor)
        client = ActionClient(g.node("bench_arm_probe"), PickAndPlace, "pick_and_place")
        assert client.wait_for_server(timeout_sec=10.0)
        for trial in all_trials:
            if floor is not None:
                floors.append(floor(trial))
            with sim.lock:
                req, mover = set_scene(sim.world, trial)
                # the arm was teleported to park: a goal that ended early had left it elsewhere
                sim.outputs.publish_due(images=False, force=True)
            g.wait_for(lambda: parked(executor.latest_joints))
            goal = PickAndPlace.Goal(block_id=mover, pick=pose(req.pick, req.pick_yaw),
                                     place=pose(req.place, req.place_yaw))
            goal.block_size.x, goal.block_size.y, goal.block_size.z = req.block_size
            t0, s0 = time.perf_counter(), sim.world.time
            handle = g.result(client.send_goal_async(goal))
            res = g.result(handle.get_result_async(), timeout=120.0).result
            walls.append(time.perf_counter() - t0)
            out = {"height": trial.height, "success": res.success, "code": res.error_code,
                   "message": res.message, "sim_s": sim.world.time - s0}
            if res.success:
                with sim.lock:
                    out.update(judge(sim.world, trial, mover, req.place))
            outcomes.append(out)
    return outcomes, walls, floors


def summarize(outcomes: list[dict]) -> dict:
    errors = [o["error_mm"] for o in outcomes if o.get("stayed")]
    stable = {}
    for h in (1, 2, 3):
        placed = [o for o in outcomes if o["height"] == h and o["success"]]
        stable[str(h)] = (round(sum(o["stayed"] for o in placed) / len(placed), 3)
                          if placed else None)
    return {
        "runs": len(outcomes),
        "pick_success": round(sum(o["success"] for o in outcomes) / len(outcomes), 3),
        "placement_error_mm": {
            "median": round(float(np.median(errors)), 2) if errors else None,
            "p95": round(float(np.percentile(errors, 95)), 2) if errors else None,
            "max": round(float(np.max(errors)), 2) if errors else None,
        },
        "action6_stable": stable,
        "failures": [o["message"] for o in outcomes if not o["success"]][:10],
        "fell": [{"height": o["height"], "error_mm": round(o["error_mm"], 1)}
                 for o in outcomes if o["success"] and not o["stayed"]][:10],
    }


def run(n: int = RUNS) -> dict:
    all_trials = trials(n)
    floor = PhysicsOnly()
    try:
        outcomes, walls, floors = through_ros(all_trials, floor)
    finally:
        floor.close()
    floor_outcomes, floor_walls = [f[0] for f in floors], [f[1] for f in floors]
    result = summarize(outcomes)
    result["pick_place_s"] = round(statistics.median(walls), 3)
    result["physics_only_s"] = round(statistics.median(floor_walls), 3)
    result["overhead_ratio"] = round(statistics.median(walls) / statistics.median(floor_walls), 2)
    result["sim_s_per_pick_place"] = round(statistics.median(o["sim_s"] for o in outcomes), 2)
    result["same_outcomes_as_physics_only"] = all(
        a["success"] == b["success"] and a.get("stayed") == b.get("stayed")
        for a, b in zip(outcomes, floor_outcomes, strict=True))
    result["physics_only"] = summarize(floor_outcomes)
    result["targets"] = {"placement_error_mm.p95": 4.0, "action6_stable": 0.98,
                         "pick_success": 0.98, "pick_place_s": 0.5}
    return result


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "physics":
        n = int(sys.argv[2]) if len(sys.argv) > 2 else RUNS
        outs, ws = physics_only(trials(n))
        print(json.dumps({**summarize(outs), "physics_only_s": statistics.median(ws)}, indent=2))
        for o in outs:
            if not o["success"] or not o.get("stayed"):
                print(o)
    else:
        print(json.dumps(run(), indent=2))
