"""Arbitrary goals for sim_node's two actions and arbitrary reset_world requests never crash or
hang the node: every one is answered (refused with a reason, or run), and the node goes on
serving valid goals."""

from __future__ import annotations

import math

import pytest
from action_msgs.msg import GoalStatus
from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory, GripperCommand
from control_msgs.msg import JointTolerance
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from katana_common.action_client import ActionClient
from katana_common.testing import wait_until
from katana_description import models as m
from katana_interfaces.srv import ResetWorld
from trajectory_msgs.msg import JointTrajectoryPoint

ANSWER_TIMEOUT_S = 120.0  # a bound against a hang, far above any answer


@pytest.fixture(scope="module")
def graph(sim_graph):
    with sim_graph("sim_property_probe", real_time_factor=0.0, camera_rate=0.0) as (sim, probe):
        yield sim, {
            "arm": ActionClient(probe, FollowJointTrajectory,
                                "arm_controller/follow_joint_trajectory"),
            "grip": ActionClient(probe, GripperCommand, "gripper_controller/gripper_command"),
            "reset": probe.create_client(ResetWorld, "sim_node/reset_world"),
        }


def _send(client, goal):
    assert client.wait_for_server(timeout_sec=10.0)
    fut = client.send_goal_async(goal)
    assert wait_until(fut.done, ANSWER_TIMEOUT_S), "no answer: the node hangs"
    handle = fut.result()
    assert handle.accepted  # refusals come with a reason in the result
    res = handle.get_result_async()
    assert wait_until(res.done, ANSWER_TIMEOUT_S), "no answer: the node hangs"
    return res.result()


floats = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                   st.floats(-4.0, 4.0), st.sampled_from([0.0, -0.0, 1e308, -1e-320]))
names = st.sampled_from([*m.ARM_JOINTS, *m.FINGER_JOINTS, "", "bogus", "katana_motor1_pan_joint"])
durations = st.builds(Duration, sec=st.integers(-(2**31), 2**31 - 1) | st.integers(0, 3),
                      nanosec=st.integers(0, 999_999_999))


@st.composite
def trajectory_goals(draw):
    goal = FollowJointTrajectory.Goal()
    joints = draw(st.lists(names, max_size=6))
    goal.trajectory.joint_names = joints
    n = len(joints) + draw(st.integers(-1, 1))
    goal.trajectory.points = [
        JointTrajectoryPoint(positions=draw(st.lists(floats, min_size=max(n, 0),
                                                     max_size=max(n, 0))),
                             velocities=draw(st.lists(floats, max_size=6)),
                             time_from_start=draw(durations))
        for _ in range(draw(st.integers(0, 4)))]
    goal.path_tolerance = [JointTolerance(name=draw(names), position=draw(floats))
                           for _ in range(draw(st.integers(0, 2)))]
    goal.goal_tolerance = [JointTolerance(name=draw(names), position=draw(floats))
                           for _ in range(draw(st.integers(0, 2)))]
    goal.goal_time_tolerance = draw(durations)
    return goal


SETTINGS = settings(max_examples=40, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture,
                                           HealthCheck.too_slow])


@SETTINGS
@given(goal=trajectory_goals())
def test_any_trajectory_goal_is_answered(graph, goal):
    _, clients = graph
    res = _send(clients["arm"], goal)
    assert res.status in (GoalStatus.STATUS_SUCCEEDED, GoalStatus.STATUS_ABORTED)
    if res.status == GoalStatus.STATUS_ABORTED:
        assert res.result.error_code != 0 or res.result.error_string  # with a reason


@SETTINGS
@given(position=floats, effort=floats)
def test_any_gripper_goal_is_answered(graph, position, effort):
    _, clients = graph
    goal = GripperCommand.Goal()
    goal.command.position, goal.command.max_effort = position, effort
    res = _send(clients["grip"], goal)
    valid = (math.isfinite(position) and m.GRIPPER_CLOSED - 1e-6 <= position
             <= m.GRIPPER_OPEN + 1e-6 and math.isfinite(effort) and effort >= 0)
    assert (res.status == GoalStatus.STATUS_SUCCEEDED) == valid


@settings(max_examples=15, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(seed=st.integers(-(2**63), 2**63 - 1))
def test_any_reset_request_is_answered(graph, seed):
    _, clients = graph
    assert clients["reset"].wait_for_service(timeout_sec=10.0)
    fut = clients["reset"].call_async(ResetWorld.Request(seed=seed))
    assert wait_until(fut.done, ANSWER_TIMEOUT_S), "no answer: the node hangs"
    resp = fut.result()
    assert resp.success, resp.message


def test_the_node_still_serves_valid_goals(graph):
    sim, clients = graph
    goal = FollowJointTrajectory.Goal()
    goal.trajectory.joint_names = ["katana_motor1_pan_joint"]
    goal.trajectory.points = [JointTrajectoryPoint(positions=[0.2],
                                                   time_from_start=Duration(sec=3))]
    res = _send(clients["arm"], goal)
    assert res.status == GoalStatus.STATUS_SUCCEEDED, res.result.error_string
    with sim.lock:
        assert abs(sim.world.joint_positions()["katana_motor1_pan_joint"] - 0.2) < 0.01
