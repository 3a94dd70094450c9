"""pick_place_executor in-process: bad goals are refused with a reason, missing servers give a
bounded TIMEOUT, and the node keeps serving."""

from __future__ import annotations

import math
import threading
import time

import pytest
import rclpy
from geometry_msgs.msg import Pose
from katana_interfaces.action import PickAndPlace
from katana_manipulation.pick_place_executor import PickPlaceExecutor
from katana_sim.sim_node import SimNode
from rclpy.action import ActionClient
from rclpy.context import Context
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter


def wait_for(cond, timeout: float = 20.0):
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, "condition not met in time"
        threading.Event().wait(0.005)


class Graph:
    def __init__(self, with_sim: bool, executor_params: list[Parameter]) -> None:
        self.ctx = Context()
        rclpy.init(context=self.ctx)
        self.nodes = []
        if with_sim:
            self.nodes.append(SimNode(context=self.ctx, parameter_overrides=[
                Parameter("real_time_factor", value=0.0), Parameter("seed", value=3)]))
        self.nodes.append(PickPlaceExecutor(context=self.ctx,
                                            parameter_overrides=executor_params))
        self.probe = Node("executor_test_probe", context=self.ctx)
        self.nodes.append(self.probe)
        self.ex = MultiThreadedExecutor(num_threads=8, context=self.ctx)
        for n in self.nodes:
            self.ex.add_node(n)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()
        self.client = ActionClient(self.probe, PickAndPlace, "pick_and_place")

    def _spin(self) -> None:
        while not self.stop.is_set():
            self.ex.spin_once(timeout_sec=0.05)

    def run(self, goal: PickAndPlace.Goal, timeout: float = 60.0):
        assert self.client.wait_for_server(timeout_sec=5.0)
        fut = self.client.send_goal_async(goal)
        wait_for(fut.done)
        handle = fut.result()
        assert handle.accepted
        res = handle.get_result_async()
        wait_for(res.done, timeout)
        return res.result()

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=5)
        self.ex.shutdown(timeout_sec=5)
        for n in self.nodes:
            n.destroy_node()
        rclpy.try_shutdown(context=self.ctx)


def _goal(pick, place, size=(0.04, 0.04, 0.03)) -> PickAndPlace.Goal:
    g = PickAndPlace.Goal()
    g.block_id = "test"
    g.pick = Pose()
    g.pick.position.x, g.pick.position.y, g.pick.position.z = pick
    g.pick.orientation.w = 1.0
    g.place = Pose()
    g.place.position.x, g.place.position.y, g.place.position.z = place
    g.place.orientation.w = 1.0
    g.block_size.x, g.block_size.y, g.block_size.z = size
    return g


@pytest.fixture(scope="module")
def sim_graph():
    g = Graph(True, [])
    yield g
    g.close()


def test_bad_goals_are_refused_with_a_reason_and_the_node_goes_on(sim_graph):
    R = PickAndPlace.Result
    res = sim_graph.run(_goal((math.nan, 0.0, 0.015), (0.2, 0.0, 0.015)))
    assert res.status == 6 and res.result.error_code == R.INVALID_GOAL
    assert "non-finite" in res.result.message
    res = sim_graph.run(_goal((0.2, 0.0, 0.015), (0.5, 0.3, 0.015)))
    assert res.result.error_code == R.UNREACHABLE and "unreachable" in res.result.message
    res = sim_graph.run(_goal((0.2, 0.0, 0.015), (0.2, 0.1, 0.015), size=(0.0, 0.04, 0.03)))
    assert res.result.error_code == R.INVALID_GOAL and "positive" in res.result.message
    # still serving: a real pick (of a block that is there) succeeds
    sim = sim_graph.nodes[0]
    with sim.lock:  # PyBullet is not thread-safe: the node steps it in its own thread
        red = next(b for b in sim.world.ground_truth() if b.id == "red")
    goal = _goal(red.position, (0.2, 0.12, 0.015))
    goal.pick.orientation.z, goal.pick.orientation.w = math.sin(red.yaw / 2), math.cos(red.yaw / 2)
    res = sim_graph.run(goal)
    assert res.result.success, res.result.message
    with sim.lock:
        moved = next(b for b in sim.world.ground_truth() if b.id == "red")
    assert math.hypot(moved.position[0] - 0.2, moved.position[1] - 0.12) < 0.005


def test_missing_arm_gives_a_bounded_timeout():
    g = Graph(False, [Parameter("server_timeout", value=0.3)])
    try:
        t0 = time.monotonic()
        res = g.run(_goal((0.2, 0.0, 0.015), (0.2, 0.1, 0.015)), timeout=10.0)
        assert res.result.error_code == PickAndPlace.Result.TIMEOUT
        assert "joint_states" in res.result.message
        assert time.monotonic() - t0 < 10.0
    finally:
        g.close()


def test_invalid_executor_parameters_name_the_parameter():
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        with pytest.raises(Exception, match="park_pose"):
            PickPlaceExecutor(context=ctx, parameter_overrides=[
                Parameter("park_pose", value=[0.0, 3.0, 0.0, 0.0, 0.0])])
        with pytest.raises(Exception, match="approach_height"):
            PickPlaceExecutor(context=ctx, parameter_overrides=[
                Parameter("approach_height", value=-1.0)])
    finally:
        rclpy.try_shutdown(context=ctx)
