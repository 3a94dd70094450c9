"""Speed of the simulation: one 640x480 render, physics speed with the arm moving, and whole
pick-and-places through the pick_and_place action (sim_node + pick_place_executor in one process,
real_time_factor 0: lock-step); bench_arm.py measures the arm in depth. `run()` returns the
figures; bench/run.py writes bench/results/sim.json.

    python bench/bench_sim.py        # prints the figures and writes bench/results/sim.json
"""

from __future__ import annotations

import json
import os
import statistics
import time
from pathlib import Path

import numpy as np
from katana_bringup.in_process import InProcessGraph
from katana_common.action_client import ActionClient
from katana_description import models as m
from katana_interfaces.action import PickAndPlace
from katana_manipulation.core.pick_place import PickPlacePlanner, PickPlaceRequest, PlanError
from katana_manipulation.core.pick_place_types import SIM_MIN_SEGMENT_TIME_S, PickPlaceParams
from katana_manipulation.pick_place_executor import PickPlaceExecutor
from katana_sim.core import PhysicsSim, SimConfig, TrajectoryGoal
from katana_sim.sim_node import SimNode
from rclpy.parameter import Parameter

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")

ROOT = Path(__file__).resolve().parents[1]


def bench_render(frames: int = 30) -> float:
    world = PhysicsSim(SimConfig(seed=1))
    try:
        world.render(fresh=True)  # warm-up
        t0 = time.perf_counter()
        for _ in range(frames):
            world.render(fresh=True)  # the renderer, not its cache
        return (time.perf_counter() - t0) / frames * 1000.0
    finally:
        world.close()


def bench_physics(sim_seconds: float = 20.0) -> float:
    """Simulated seconds per wall second with the arm sweeping back and forth (no rendering),
    the physics engine stepping throughout (the sweep is free space, which the sim would
    otherwise cross without it)."""
    world = PhysicsSim(SimConfig(seed=1, kinematic_free_space=False))
    try:
        a = list(m.PARK_POSE)
        b = [0.5, 1.2, -1.5, 1.2, 0.5]
        speeds = np.array([m.JOINT_MAX_SPEED[n] for n in m.ARM_JOINTS])
        dur = 1.6 * float(np.max(np.abs(np.subtract(a, b)) / speeds))
        t0, s0 = time.perf_counter(), world.time
        target = b
        while world.time - s0 < sim_seconds:
            h = world.start_trajectory(TrajectoryGoal(list(m.ARM_JOINTS), [dur], [target]))
            world.start_gripper(m.GRIPPER_CLOSED if target is b else m.GRIPPER_OPEN)
            while h.outcome.status == "running":
                world.step(12)
            target = a if target is b else b
        return (world.time - s0) / (time.perf_counter() - t0)
    finally:
        world.close()


def bench_pick_place(runs: int = 5) -> tuple[float, float, int]:
    """Median wall seconds of one pick-and-place through the action (sim_node and
    pick_place_executor in one process, the fast lock-step sim), its sim/wall speed, and how many
    succeeded."""
    planner = PickPlacePlanner(params=PickPlaceParams(min_segment_time=SIM_MIN_SEGMENT_TIME_S))
    walls, speeds, ok = [], [], 0
    with InProcessGraph() as g:
        sim = SimNode(context=g.context, parameter_overrides=[
            Parameter("real_time_factor", value=0.0), Parameter("seed", value=0),
            Parameter("use_sim_time", value=True)])
        g.add(sim, PickPlaceExecutor(context=g.context, parameter_overrides=[  # as sim.yaml
            Parameter("use_sim_time", value=True),
            Parameter("min_segment_time_s", value=SIM_MIN_SEGMENT_TIME_S)]))
        probe = g.node("bench_sim_probe")
        client = ActionClient(probe, PickAndPlace, "pick_and_place")
        assert client.wait_for_server(timeout_sec=10.0)
        seed = 0
        while len(walls) < runs:
            seed += 1
            with sim.lock:
                blocks = sim.world.reset(seed)
            a, b = blocks[0], blocks[1]
            req = PickPlaceRequest(a.position, a.yaw, a.size,
                                   (b.position[0], b.position[1], b.position[2] + b.size[2]), b.yaw)
            try:  # only pairs the arm can reach: this measures speed, not reach
                with sim.lock:
                    planner.plan(req, list(sim.world.joint_positions().values())[:5])
            except PlanError:
                continue
            msg = sim.ground_truth_msg()
            ga, gb = msg.blocks[0], msg.blocks[1]
            goal = PickAndPlace.Goal(block_id=ga.id, pick=ga.pose, block_size=ga.size)
            goal.place = gb.pose
            goal.place.position.z += gb.size.z
            s0, t0 = sim.world.time, time.perf_counter()
            handle = g.result(client.send_goal_async(goal))
            res = g.result(handle.get_result_async(), timeout=120.0)
            wall = time.perf_counter() - t0
            walls.append(wall)
            speeds.append((sim.world.time - s0) / wall)
            ok += int(res.result.success)
    return statistics.median(walls), statistics.median(speeds), ok


def run() -> dict:
    render_ms = bench_render()
    rtf = bench_physics()
    pick_place_s, pp_rtf, ok = bench_pick_place()
    return {
        "render_ms": round(render_ms, 2),
        "real_time_factor": round(rtf, 1),
        "pick_place_s": round(pick_place_s, 3),
        "pick_place_real_time_factor": round(pp_rtf, 1),
        "pick_place_succeeded": ok,
        "pick_place_runs": 5,
        "targets": {"render_ms": 30.0, "pick_place_s": 0.5},
    }


if __name__ == "__main__":
    result = run()
    print(json.dumps(result, indent=2))
    out = ROOT / "bench" / "results"
    out.mkdir(parents=True, exist_ok=True)
    (out / "sim.json").write_text(json.dumps(result, indent=2) + "\n")
