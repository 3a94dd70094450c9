"""pick_place_executor in-process: bad goals are refused with a reason, missing servers give a
bounded TIMEOUT, and the node keeps serving."""

from __future__ import annotations

import math
import threading

import pytest
import rclpy
from action_msgs.msg import GoalStatus
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Pose
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from katana_common import params as common
from katana_common.action_client import ActionClient
from katana_common.executor import MultiThreadedExecutor
from katana_common.qos import JOINT_STATE_QOS
from katana_common.testing import wait_until
from katana_description import models as m
from katana_interfaces.action import PickAndPlace
from katana_manipulation.core import pick_place as pp
from katana_manipulation.core.reach import place_reach
from katana_manipulation.pick_place_executor import PARAMS, PickPlaceExecutor
from katana_manipulation.reach_params import REACH_PARAMS, reach_geometry
from katana_sim.sim_node import SimNode
from rcl_interfaces.srv import SetParameters
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Header


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
        assert wait_until(fut.done, 20.0)
        handle = fut.result()
        assert handle.accepted
        res = handle.get_result_async()
        assert wait_until(res.done, timeout)
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


R = PickAndPlace.Result
TABLE = (0.2, 0.0, 0.015)


@pytest.mark.parametrize(
    ("pick", "place", "size", "code", "why"),
    [
        ((math.nan, 0.0, 0.015), (0.2, 0.0, 0.015), None, R.INVALID_GOAL, "non-finite"),
        ((0.2, 0.0, 0.015), (0.2, math.inf, 0.015), None, R.INVALID_GOAL, "non-finite"),
        ((0.2, 0.0, -0.06), TABLE, None, R.INVALID_GOAL, "below the table top"),
        ((0.2, 0.0, -0.2), TABLE, None, R.INVALID_GOAL, "below the table top"),
        (TABLE, (0.2, 0.1, -0.06), None, R.INVALID_GOAL, "below the table top"),
        (TABLE, (0.5, 0.3, 0.015), None, R.PLACE_UNREACHABLE, "place"),
        (TABLE, (3.0, 0.0, 0.015), None, R.PLACE_UNREACHABLE, "outside the workspace"),
        ((0.5, -0.3, 0.015), TABLE, None, R.PICK_UNREACHABLE, "pick"),
        # on a stack of three the arm reaches less far than on the table
        (TABLE, (0.25, 0.0, 0.105), None, R.PLACE_UNREACHABLE, "height 3"),
        ((0.2, 0.05, 0.105), TABLE, None, R.PICK_UNREACHABLE, "height 3"),
        (TABLE, (0.2, 0.1, 0.015), (0.0, 0.04, 0.03), R.INVALID_GOAL, "positive"),
    ],
)
def test_bad_goals_are_refused_with_a_reason(sim_graph, pick, place, size, code, why):
    res = sim_graph.run(_goal(pick, place, size or (0.04, 0.04, 0.03)))
    assert res.status == GoalStatus.STATUS_ABORTED
    assert res.result.error_code == code and why in res.result.message, res.result.message


def test_after_bad_goals_a_real_pick_succeeds(sim_graph):
    sim = sim_graph.nodes[0]
    before = sim.world.joint_positions()
    res = sim_graph.run(_goal((0.2, 0.0, -0.2), TABLE))
    assert res.result.error_code == R.INVALID_GOAL
    with sim.lock:  # PyBullet is not thread-safe
        assert sim.world.joint_positions() == before  # a refused goal moved nothing
        red = next(b for b in sim.world.ground_truth() if b.id == "red")
    goal = _goal(red.position, (0.2, 0.12, 0.015))
    goal.pick.orientation.z, goal.pick.orientation.w = math.sin(red.yaw / 2), math.cos(red.yaw / 2)
    res = sim_graph.run(goal)
    assert res.status == GoalStatus.STATUS_SUCCEEDED and res.result.success, res.result.message
    with sim.lock:
        moved = next(b for b in sim.world.ground_truth() if b.id == "red")
    assert math.hypot(moved.position[0] - 0.2, moved.position[1] - 0.12) < 0.005


def test_core_result_codes_equal_the_interface_constants():
    names = [n for n in dir(R) if n.isupper() and isinstance(getattr(R, n), int)]
    assert {"PICK_UNREACHABLE", "PLACE_UNREACHABLE", "UNREACHABLE"} <= set(names)
    for name in names:
        assert getattr(pp, name) == getattr(R, name), name


def test_live_parameters_apply_and_read_only_ones_are_refused(sim_graph):
    executor = sim_graph.nodes[1]
    client = sim_graph.probe.create_client(SetParameters,
                                           "pick_place_executor/set_parameters")
    assert client.wait_for_service(timeout_sec=5.0)

    def set_(name, value):
        req = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])
        fut = client.call_async(req)
        assert wait_until(fut.done, 20.0)
        return fut.result().results[0]

    assert set_("speed_fraction", 0.8).successful
    assert executor.planner.p.speed_fraction == 0.8  # the next goal plans with it
    bad = set_("speed_fraction", 2.0)
    assert not bad.successful and "speed_fraction" in bad.reason
    assert executor.planner.p.speed_fraction == 0.8
    ro = set_("model", "400_6m180")
    assert not ro.successful and "read-only" in ro.reason
    assert set_("speed_fraction", 0.9).successful
    # the geometry the reach depends on is set once for the graph, at start-up
    for name in ("grasp_offset", "approach_height"):
        ro = set_(name, 0.01)
        assert not ro.successful and "read-only" in ro.reason, name
    assert executor.planner.p.geometry == pp.PickPlaceParams().geometry


def test_the_executor_plans_with_its_geometry_and_checks_the_reach_with_it():
    """grasp_offset and approach_height given at start-up (as graph.yaml's `/**` gives them to
    every node) reach the planner, and the executor refuses a place that their reach excludes
    though the default geometry's reach includes it."""
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        executor = PickPlaceExecutor(context=ctx, parameter_overrides=[
            Parameter("grasp_offset", value=0.012), Parameter("approach_height", value=0.045)])
        p = executor.planner.p
        assert (p.grasp_offset, p.approach_height) == (0.012, 0.045)
        assert reach_geometry(executor.params) == p.geometry
        narrow, wide = place_reach(2, 0.03, geometry=p.geometry), place_reach(2, 0.03)
        r = 0.5 * (narrow.max_m + wide.max_m)
        req = pp.PickPlaceRequest(TABLE, 0.0, (0.04, 0.04, 0.03), (r, 0.0, 0.075), 0.0)
        with pytest.raises(pp.PlanError, match="outside the reach"):
            executor.planner.plan(req, pp.PickPlaceParams().park_pose)
        pp.PickPlacePlanner().plan(req, pp.PickPlaceParams().park_pose)  # the default: in reach
        executor.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


def test_the_shared_geometry_is_one_definition_and_every_node_accepts_it():
    """REACH_PARAMS are the executor's own specs, their defaults are the planner's, and
    katana_common lets every other node receive them under `/**` without declaring them."""
    by_name = {p.name: p for p in PARAMS}
    assert all(by_name[p.name] is p for p in REACH_PARAMS)
    assert tuple(sorted(p.name for p in REACH_PARAMS)) == tuple(sorted(
        common.GRAPH_WIDE_GEOMETRY))
    defaults = pp.PickPlaceParams()
    assert all(p.default == getattr(defaults, p.name) and not p.live for p in REACH_PARAMS)
    assert by_name["min_segment_time_s"].default == defaults.min_segment_time \
        == pp.MIN_SEGMENT_TIME_S


def test_missing_arm_gives_a_bounded_timeout():
    g = Graph(False, [Parameter("server_timeout_s", value=0.3)])
    try:
        res = g.run(_goal((0.2, 0.0, 0.015), (0.2, 0.1, 0.015)), timeout=10.0)
        assert res.result.error_code == PickAndPlace.Result.TIMEOUT
        assert "joint_states" in res.result.message
    finally:
        g.close()


def test_a_goal_waits_for_joint_states_stamped_after_its_joint_states_after():
    """A world reset moves the arm outside the executor's goals: a goal naming the reset's
    stamp plans only from joint_states stamped at or after it, and says so when none come."""
    g = Graph(False, [Parameter("server_timeout_s", value=1.0)])
    pub = g.probe.create_publisher(JointState, "joint_states", JOINT_STATE_QOS)

    def joints_at(sec: int) -> None:
        pub.publish(JointState(header=Header(stamp=Time(sec=sec)), name=list(m.ALL_JOINTS),
                               position=[*m.PARK_POSE, m.GRIPPER_OPEN, m.GRIPPER_OPEN]))

    try:
        assert wait_until(lambda: pub.get_subscription_count() > 0)
        joints_at(10)
        executor = g.nodes[0]
        assert wait_until(lambda: executor.latest_joints_ns == 10 * 10**9)
        goal = _goal((0.2, 0.0, 0.015), (0.2, 0.1, 0.015))
        goal.joint_states_after = Time(sec=20)
        res = g.run(goal, timeout=10.0)
        assert res.result.error_code == R.TIMEOUT
        assert "joint_states_after" in res.result.message, res.result.message
        # joint_states stamped at the reset come while the goal waits: it goes on to the arm
        # (here no arm answers: a timeout naming the gripper action, not the joint states)
        timer = threading.Timer(0.3, joints_at, (20,))
        timer.start()
        res = g.run(goal, timeout=10.0)
        timer.join()
        assert executor.latest_joints_ns == 20 * 10**9
        assert res.result.error_code == R.TIMEOUT
        assert "joint_states" not in res.result.message and "gripper" in res.result.message, \
            res.result.message
    finally:
        g.close()


@pytest.mark.parametrize("true_pose_comes", [True, False])
def test_a_task_starts_from_joint_states_that_show_the_arm_where_the_last_task_left_it(
        true_pose_comes):
    """joint_states taken late, from before the last motion ended, must not become the next
    task's start: it waits (at most SETTLE_WAIT_S) for the arm shown where the last move sent
    it and the fingers where the last grip left them, and starts from the latest otherwise."""
    g = Graph(False, [Parameter("server_timeout_s", value=1.0)])
    pub = g.probe.create_publisher(JointState, "joint_states", JOINT_STATE_QOS)
    stale = [m.PARK_POSE[0] + 0.2, *m.PARK_POSE[1:]]

    def joints_at(sec: int, arm) -> None:
        pub.publish(JointState(header=Header(stamp=Time(sec=sec)), name=list(m.ALL_JOINTS),
                               position=[*arm, m.GRIPPER_OPEN, m.GRIPPER_OPEN]))

    try:
        assert wait_until(lambda: pub.get_subscription_count() > 0)
        executor = g.nodes[0]
        # the last task left the arm parked with the fingers open; its joint_states lag
        executor.port.commanded, executor.port.gripped = list(m.PARK_POSE), m.GRIPPER_OPEN
        joints_at(10, stale)
        assert wait_until(lambda: executor.latest_joints_ns == 10 * 10**9)
        starts = []
        read = executor.port.joint_positions

        def reading(*args, **kwargs):
            starts.append(read(*args, **kwargs))
            return starts[-1]

        executor.port.joint_positions = reading
        timer = threading.Timer(0.3, joints_at, (11, m.PARK_POSE)) if true_pose_comes else None
        if timer is not None:
            timer.start()
        res = g.run(_goal((0.2, 0.0, 0.015), (0.2, 0.1, 0.015)), timeout=10.0)
        if timer is not None:
            timer.join()
        assert res.result.error_code == R.TIMEOUT  # no arm answers here
        first = starts[0][m.ARM_JOINTS[0]]
        assert first == pytest.approx(m.PARK_POSE[0] if true_pose_comes else stale[0])
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


coords = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-0.4, 0.4),
                   st.sampled_from([0.015, 0.045, -0.06, 1e308]))


@st.composite
def pick_place_goals(draw):
    goal = PickAndPlace.Goal(block_id=draw(st.text(max_size=8)))
    for pose in (goal.pick, goal.place):
        pose.position.x, pose.position.y, pose.position.z = (draw(coords) for _ in range(3))
        o = pose.orientation
        o.x, o.y, o.z, o.w = (draw(st.floats(allow_nan=True, allow_infinity=True)
                                   | st.floats(-1, 1)) for _ in range(4))
    goal.block_size.x, goal.block_size.y, goal.block_size.z = (
        draw(st.floats(allow_nan=True, allow_infinity=True) | st.just(0.04)) for _ in range(3))
    # stamps the sim's joint_states pass within its first seconds (the far future: above)
    goal.joint_states_after = Time(sec=draw(st.integers(0, 1)),
                                   nanosec=draw(st.integers(0, 999_999_999)))
    return goal


@settings(max_examples=30, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(goal=pick_place_goals())
def test_any_pick_and_place_goal_is_answered(sim_graph, goal):
    res = sim_graph.run(goal, timeout=120.0)
    assert res.status in (GoalStatus.STATUS_SUCCEEDED, GoalStatus.STATUS_ABORTED)
    assert res.result.success == (res.status == GoalStatus.STATUS_SUCCEEDED)
    if not res.result.success:
        assert res.result.message  # always with a reason
        codes = {getattr(R, n) for n in dir(R) if n.isupper() and isinstance(getattr(R, n), int)}
        assert res.result.error_code in codes - {R.SUCCESS}
