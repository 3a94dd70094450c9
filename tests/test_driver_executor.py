"""pick_place_executor drives the EMULATED arm through the driver's actions (a whole-graph test:
katana_driver and katana_manipulation together), also with spline replies delayed 0.6 s."""

import pytest
import rclpy
from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory
from geometry_msgs.msg import Pose, Vector3
from katana_common.action_client import ActionClient
from katana_common.executor import MultiThreadedExecutor
from katana_common.testing import spin_until
from katana_description import models
from katana_driver.core.encoders import ARM_JOINTS
from katana_driver.katana_driver_node import KatanaDriverNode
from katana_emulator.emulator import Faults, KatanaEmulator, KatanaModel
from katana_interfaces.action import PickAndPlace
from katana_manipulation.pick_place_executor import PickPlaceExecutor
from rclpy.action.client import GoalStatus
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from trajectory_msgs.msg import JointTrajectoryPoint

pytestmark = pytest.mark.timeout(120)


@pytest.fixture
def emulator():
    # A 4 cm block between the fingers: the emulated gripper stalls where a block holds it.
    block = models.BLOCK_SIZE[0]
    made = KatanaEmulator(KatanaModel(calibrated=True, time_scale=2.0, block_width_m=block),
                          Faults())
    made.serve_tcp("127.0.0.1", 0)
    yield made
    made.stop()


def pose(x, y, z):
    p = Pose()
    p.position.x, p.position.y, p.position.z = x, y, z
    p.orientation.w = 1.0
    return p


@pytest.mark.parametrize("spline_latency_s", [0.0, 0.6], ids=["prompt", "spline_replies_late"])
def test_executor_picks_and_places_on_the_emulated_arm(emulator, spline_latency_s):
    """Also with replies to spline commands 0.6 s late (past the driver's 0.5 s timeout): a
    driver that re-sends a segment then makes the arm jump (it ended 0.17 rad from the goal),
    so no segment may arrive twice and the arm must end parked."""
    host, port = emulator.address
    ctx = Context()
    rclpy.init(context=ctx)
    driver = KatanaDriverNode(
        node_name="katana_driver_exec_test",
        context=ctx,
        parameter_overrides=[Parameter("host", value=host), Parameter("port", value=port)],
    )
    executor_node = PickPlaceExecutor(context=ctx)
    client_node = Node("pick_place_test_client", context=ctx)
    client = ActionClient(client_node, PickAndPlace, "pick_and_place")
    executor = MultiThreadedExecutor(num_threads=8, context=ctx)
    for node in (driver, executor_node, client_node):
        executor.add_node(node)

    try:
        assert spin_until(executor, lambda: driver.ready and client.server_is_ready(), 15.0)
        # Fresh from calibration every motor sits on its stop, where the executor's inverse
        # kinematics refuses to start; park first, as the experiment does.
        park = list(executor_node.planner.p.park_pose)
        arm = ActionClient(
            client_node, FollowJointTrajectory, "arm_controller/follow_joint_trajectory"
        )
        assert spin_until(executor, arm.server_is_ready, 5.0)
        to_park = FollowJointTrajectory.Goal()
        to_park.trajectory.joint_names = list(ARM_JOINTS)
        to_park.trajectory.points = [
            JointTrajectoryPoint(positions=park, time_from_start=Duration(sec=4))
        ]
        parked = arm.send_goal_async(to_park)
        assert spin_until(executor, parked.done, 5.0)
        parked_result = parked.result().get_result_async()
        assert spin_until(executor, parked_result.done, 15.0)
        assert parked_result.result().status == GoalStatus.STATUS_SUCCEEDED
        emulator.model.reset_counters()
        emulator.faults.spline_latency_s = spline_latency_s
        goal = PickAndPlace.Goal(
            block_id="red",
            pick=pose(0.22, 0.06, 0.015),
            block_size=Vector3(x=0.04, y=0.04, z=0.03),
            place=pose(0.22, -0.06, 0.015),
        )
        phases = []
        sent = client.send_goal_async(
            goal, feedback_callback=lambda f: phases.append(f.feedback.phase)
        )
        assert spin_until(executor, sent.done, 10.0) and sent.result().accepted
        result = sent.result().get_result_async()
        assert spin_until(executor, result.done, 100.0)
        res = result.result()
        assert res.status == GoalStatus.STATUS_SUCCEEDED, res.result.message
        assert res.result.success
        assert {"grasp", "carry", "release", "park"} <= set(phases)
        # The arm ends parked (the executor's park pose), as read from the emulated encoders.
        parked = driver.worker.state.positions[:5]
        assert parked == pytest.approx(list(executor_node.planner.p.park_pose), abs=0.01)
        assert emulator.model.duplicated_segments == 0
        assert emulator.model.max_speed_ratio <= 1.05, f"motor {emulator.model.max_speed_motor}"
    finally:
        executor.shutdown()
        for node in (driver, executor_node, client_node):
            node.destroy_node()
        rclpy.shutdown(context=ctx)
