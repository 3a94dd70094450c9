"""sim_node in-process: camera, joint_states, actions, reset_world, bad input, parameters."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
import rclpy
from action_msgs.msg import GoalStatus
from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory, GripperCommand
from control_msgs.msg import JointComponentTolerance
from diagnostic_msgs.msg import DiagnosticArray
from katana_common.action_client import ActionClient
from katana_common.messages import to_seconds
from katana_common.qos import DIAGNOSTICS_QOS, JOINT_STATE_QOS, SENSOR_QOS, STATE_QOS
from katana_common.testing import wait_until
from katana_description import arm_contract as ac
from katana_description import models as m
from katana_interfaces.msg import BlockArray
from katana_interfaces.srv import ResetWorld
from katana_sim.sim_node import FAST_IMAGE_STANDING_S, SimNode
from rcl_interfaces.srv import SetParameters
from rclpy.context import Context
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, Image, JointState
from trajectory_msgs.msg import JointTrajectoryPoint, MultiDOFJointTrajectoryPoint


@pytest.fixture(scope="module")
def graph(sim_graph):
    with sim_graph("sim_test_probe", real_time_factor=0.0, seed=5, camera_rate=20.0) as (
            sim, probe):
        got: dict = {}
        probe.create_subscription(Image, "camera/image_raw", lambda msg: got.update(image=msg),
                                  SENSOR_QOS)
        probe.create_subscription(CameraInfo, "camera/camera_info",
                                  lambda msg: got.update(info=msg), SENSOR_QOS)
        probe.create_subscription(JointState, "joint_states", lambda msg: got.update(joints=msg),
                                  JOINT_STATE_QOS)
        probe.create_subscription(BlockArray, "sim/ground_truth",
                                  lambda msg: got.update(truth=msg), STATE_QOS)
        arm = ActionClient(probe, FollowJointTrajectory, "arm_controller/follow_joint_trajectory")
        grip = ActionClient(probe, GripperCommand, "gripper_controller/gripper_command")
        reset = probe.create_client(ResetWorld, "sim_node/reset_world")
        yield {"sim": sim, "probe": probe, "got": got, "arm": arm, "grip": grip, "reset": reset}


def _result(future, timeout: float = 20.0):
    assert wait_until(future.done, timeout), "no result in time"
    return future.result()


def _send(client, goal):
    assert client.wait_for_server(timeout_sec=5.0)
    handle = _result(client.send_goal_async(goal))
    assert handle.accepted
    return _result(handle.get_result_async())


def _traj(names, points, times) -> FollowJointTrajectory.Goal:
    goal = FollowJointTrajectory.Goal()
    goal.trajectory.joint_names = names
    goal.trajectory.points = [
        JointTrajectoryPoint(positions=q, time_from_start=Duration(
            sec=int(t), nanosec=int((t - int(t)) * 1e9)))
        for q, t in zip(points, times, strict=True)
    ]
    return goal


def test_camera_images_and_info(graph):
    got = graph["got"]
    assert wait_until(lambda: "image" in got and "info" in got and "truth" in got)
    img, info = got["image"], got["info"]
    assert (img.width, img.height, img.encoding, img.step) == (640, 480, "rgb8", 640 * 3)
    assert img.header.frame_id == "camera_optical_frame" == info.header.frame_id
    arr = np.frombuffer(bytes(img.data), np.uint8).reshape(480, 640, 3)
    k = np.array(info.k).reshape(3, 3)
    assert np.allclose(k, [[750, 0, 319.5], [0, 750, 239.5], [0, 0, 1]])
    # every block's projected top centre shows that block's colour
    for blk in got["truth"].blocks:
        u, v = round(blk.pixel_u), round(blk.pixel_v)
        pix = arr[v - 3:v + 4, u - 3:u + 4].reshape(-1, 3).mean(axis=0)
        ref = np.array(m.COLOURS[blk.color][:3]) * 255
        cos = pix @ ref / (np.linalg.norm(pix) * np.linalg.norm(ref))
        assert cos > 0.97, (blk.color, pix, ref)


def test_joint_states_carry_seven_joints(graph):
    got = graph["got"]
    assert wait_until(lambda: "joints" in got)
    js = got["joints"]
    assert list(js.name) == list(m.ALL_JOINTS)
    assert len(js.position) == len(js.velocity) == 7
    assert abs(js.position[5] - js.position[6]) < 1e-3


def test_trajectory_and_gripper_actions(graph):
    got = graph["got"]
    target = [0.3, 1.2, -1.5, 1.2, 0.4]
    res = _send(graph["arm"], _traj(list(m.ARM_JOINTS), [target], [4.0]))
    assert res.result.error_code == 0, res.result.error_string
    assert wait_until(lambda: np.allclose(got["joints"].position[:5], target, atol=0.01))
    res = _send(graph["grip"], GripperCommand.Goal())  # position 0, default effort
    assert res.result.reached_goal and abs(res.result.position) < 0.011


def test_the_fast_sim_images_only_an_arm_out_of_view(graph):
    """Fast mode: an arm standing over the table is not imaged (until it has stood there
    FAST_IMAGE_STANDING_S), and once it parks the changed scene is imaged."""
    probe, sim = graph["probe"], graph["sim"]
    stamps: list[float] = []
    sub = probe.create_subscription(
        Image, "camera/image_raw",
        lambda msg: stamps.append(to_seconds(msg.header.stamp)),
        SENSOR_QOS)
    try:
        over_table = [0.0, 1.234239, -1.075592, 1.729443, 0.0]  # tool at (0.2, 0, 0.1)
        assert _send(graph["arm"], _traj(list(m.ARM_JOINTS), [over_table], [6.0])).result \
            .error_code == 0
        stood = sim.world.time  # the motion's end (the world is frozen since)
        assert sim.world.arm_in_view()
        time.sleep(0.6 * FAST_IMAGE_STANDING_S)
        assert not [t for t in stamps if t >= stood - 1e-9]
        assert _send(graph["arm"], _traj(list(m.ARM_JOINTS), [list(m.PARK_POSE)], [6.0])) \
            .result.error_code == 0
        parked = sim.world.time
        assert not sim.world.arm_in_view()
        assert wait_until(lambda: [t for t in stamps if t >= parked - 1e-9], 5.0)
    finally:
        probe.destroy_subscription(sub)


@pytest.mark.parametrize(
    ("names", "points", "times", "code", "why"),
    [
        (["katana_motor1_pan_joint"], [[math.nan]], [1.0], -1, "not finite"),
        (["no_such_joint"], [[0.0]], [1.0], -2, "unknown"),
        (["katana_motor2_lift_joint"], [[2.5]], [5.0], -1, "outside"),
        (["katana_motor1_pan_joint"], [[2.8]], [0.2], -1, "rad/s"),
        ([], [], [], -2, "no joint names"),
    ],
)
def test_bad_trajectories_are_refused_and_the_node_goes_on(graph, names, points, times, code,
                                                           why):
    res = _send(graph["arm"], _traj(names, points, times))
    assert res.result.error_code == code and why in res.result.error_string
    assert res.status == GoalStatus.STATUS_ABORTED  # with the reason in the result
    # slow enough from any pan angle: under pytest-xdist the case may be its worker's first
    # goal, with the arm still parked at pan -3.0
    ok = _send(graph["arm"], _traj(["katana_motor1_pan_joint"], [[0.1]], [6.0]))
    assert ok.result.error_code == 0, ok.result.error_string


def test_a_goal_of_too_many_points_is_refused_before_its_points_are_read(graph):
    """A hundred thousand points, each with a NaN the contract would name: the refusal is about
    the count (checked first), and the node goes on."""
    n = 100_000
    goal = _traj(["katana_motor1_pan_joint"], [[math.nan]] * n, [0.001 * (i + 1) for i in range(n)])
    res = _send(graph["arm"], goal)
    assert res.status == GoalStatus.STATUS_ABORTED
    assert res.result.error_code == FollowJointTrajectory.Result.INVALID_GOAL
    assert f"{n} points; at most {ac.MAX_TRAJECTORY_POINTS}" in res.result.error_string
    ok = _send(graph["arm"], _traj(["katana_motor1_pan_joint"], [[0.1]], [6.0]))
    assert ok.result.error_code == 0, ok.result.error_string


def test_the_sim_reports_its_pace_on_diagnostics(graph):
    """Fast mode: OK, as fast as it can go, with the simulated time it has reached."""
    statuses: list = []
    graph["probe"].create_subscription(DiagnosticArray, "/diagnostics",
                                       lambda msg: statuses.extend(msg.status), DIAGNOSTICS_QOS)
    assert wait_until(lambda: len(statuses) >= 2, 10.0), "two statuses (about 2 s)"
    status = statuses[-1]
    values = {kv.key: kv.value for kv in status.values}
    assert status.name == "sim_node: physics" and status.level == b"\x00"
    assert values["target_real_time_factor"] == "as fast as possible"
    assert float(values["sim_time_s"]) >= 0.0 and float(values["real_time_factor"]) >= 0.0


def _multi_dof_joint(goal: FollowJointTrajectory.Goal) -> None:
    goal.multi_dof_trajectory.joint_names = ["base_floating"]
    goal.multi_dof_trajectory.points = [MultiDOFJointTrajectoryPoint()]


def _component_tolerance(goal: FollowJointTrajectory.Goal) -> None:
    goal.component_goal_tolerance = [JointComponentTolerance(
        joint_name="base_floating", component=JointComponentTolerance.TRANSLATION, position=0.1)]


@pytest.mark.parametrize("add_multi_dof", [_multi_dof_joint, _component_tolerance])
def test_multi_dof_parts_are_refused_with_invalid_joints(graph, add_multi_dof):
    """control_msgs' goal has multi-DOF parts; the Katana has no such joint: refused whole,
    even when its single-DOF trajectory alone would run."""
    goal = _traj(["katana_motor1_pan_joint"], [[0.1]], [6.0])
    add_multi_dof(goal)
    res = _send(graph["arm"], goal)
    assert res.status == GoalStatus.STATUS_ABORTED
    assert res.result.error_code == FollowJointTrajectory.Result.INVALID_JOINTS
    assert "base_floating" in res.result.error_string


def test_bad_gripper_goal_is_refused(graph):
    goal = GripperCommand.Goal()
    goal.command.position = 1.5
    res = _send(graph["grip"], goal)
    assert res.status == GoalStatus.STATUS_ABORTED and not res.result.reached_goal


def test_reset_world_scatters_again(graph):
    got = graph["got"]
    assert wait_until(lambda: "truth" in got)
    cli = graph["reset"]
    assert cli.wait_for_service(timeout_sec=5.0)
    resp = _result(cli.call_async(ResetWorld.Request(seed=42)))
    assert resp.success and "seed 42" in resp.message
    assert wait_until(lambda: graph["sim"].world.last_seed == 42)
    sim = graph["sim"]
    first = [(b.pose.position.x, b.pose.position.y) for b in sim.ground_truth_msg().blocks]
    stamps: list = []
    sub = graph["probe"].create_subscription(BlockArray, "sim/ground_truth", stamps.append,
                                             STATE_QOS)
    try:
        resp = _result(cli.call_async(ResetWorld.Request(seed=-1)))
        assert resp.success
        second = [(b.pose.position.x, b.pose.position.y) for b in sim.ground_truth_msg().blocks]
        assert not np.allclose(first, second)
        # the answer says from when the new scene stands: what is stamped from then on shows it
        stood = to_seconds(resp.stamp)
        assert 0.0 < stood <= sim.world.time + 1e-9  # (nanoseconds, rounded)
        assert wait_until(lambda: any(to_seconds(m.header.stamp) >= stood for m in stamps))
        after = [m for m in stamps if to_seconds(m.header.stamp) >= stood]
        for msg in after:
            assert np.allclose([(b.pose.position.x, b.pose.position.y) for b in msg.blocks],
                               second, atol=1e-6)
    finally:
        graph["probe"].destroy_subscription(sub)
    assert all(b.level == 1 and b.visible for b in graph["sim"].ground_truth_msg().blocks)


def test_reset_world_publishes_the_reset_arm_before_it_answers(graph):
    """A pick-and-place asked for after a reset must plan from the parked arm with open
    fingers: joint_states stamped at the reset's stamp go out before the answer (the fast sim
    otherwise publishes them at most every 0.1 s of wall time, and an executor holding the
    fingers of before decided to skip its opening grip, a different task under load)."""
    sim, probe = graph["sim"], graph["probe"]
    closed = 0.5 * (m.GRIPPER_OPEN + m.GRIPPER_CLOSED)
    grip = GripperCommand.Goal()
    grip.command.position, grip.command.max_effort = closed, 0.0
    assert _send(graph["grip"], grip).status == GoalStatus.STATUS_SUCCEEDED
    states: list[JointState] = []
    sub = probe.create_subscription(JointState, "joint_states", states.append, JOINT_STATE_QOS)
    try:
        assert wait_until(lambda: states)
        resp = _result(graph["reset"].call_async(ResetWorld.Request(seed=7)))
        assert resp.success
        # the pacing thread's next joint_states are stamped later: it advances the clock first
        assert wait_until(lambda: any(s.header.stamp == resp.stamp for s in states), 2.0), \
            "no joint_states stamped at the reset: not published with it"
        at_reset = [s for s in states if s.header.stamp == resp.stamp]
        pos = dict(zip(at_reset[-1].name, at_reset[-1].position, strict=True))
        assert [pos[n] for n in m.ARM_JOINTS] == pytest.approx(m.PARK_POSE, abs=1e-3)
        assert [pos[n] for n in m.FINGER_JOINTS] == pytest.approx(
            [m.GRIPPER_OPEN] * len(m.FINGER_JOINTS), abs=1e-3)
    finally:
        probe.destroy_subscription(sub)
    assert sim.world.last_seed == 7


@pytest.mark.parametrize(
    ("param", "value"),
    [
        ("num_blocks", 9),
        ("block_colors", ["red"] * 8),
        ("physics_rate", -5.0),
        ("real_time_factor", -1.0),
        ("block_size", [0.04, 0.04]),
    ],
)
def test_invalid_parameters_stop_the_node_naming_them(param, value):
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        overrides = [Parameter(param, value=value)]
        if param == "block_colors":
            overrides.append(Parameter("num_blocks", value=8))
        with pytest.raises(Exception, match=param):
            SimNode(context=ctx, parameter_overrides=overrides)
    finally:
        rclpy.try_shutdown(context=ctx)


def test_stamps_are_simulated_time(graph):
    got, sim = graph["got"], graph["sim"]
    assert wait_until(lambda: "joints" in got and "truth" in got)
    for msg in (got["joints"], got["truth"]):
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        assert 0.0 <= stamp <= sim.world.time + 1e-6  # sim time since start-up, not the epoch


def _set(graph, name, value):
    client = graph["probe"].create_client(SetParameters, "sim_node/set_parameters")
    assert client.wait_for_service(timeout_sec=5.0)
    req = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])
    return _result(client.call_async(req)).results[0]


def test_rates_apply_live_and_world_parameters_are_read_only(graph):
    sim = graph["sim"]
    assert _set(graph, "camera_rate", 4.0).successful
    assert sim.outputs.schedule.period("camera") == 0.25  # the next image is due 0.25 s later
    bad = _set(graph, "camera_rate", 500.0)
    assert not bad.successful and "camera_rate" in bad.reason
    assert sim.outputs.schedule.period("camera") == 0.25
    ro = _set(graph, "num_blocks", 2)
    assert not ro.successful and "read-only" in ro.reason
    assert len(sim.world.blocks) == 4
    assert _set(graph, "camera_rate", 20.0).successful
