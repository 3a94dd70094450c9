"""The simulated graph built by katana-run's build_nodes, seen through rclpy: names and types of
docs/DESIGN.md's node graph, one stacking pick-and-place through the action, and block memory
following a pick-and-place sent by hand, on the simulation's clock."""

from __future__ import annotations

import math

from katana_bringup.run import build_nodes, default_params_files, load_params
from katana_common.action_client import ActionClient
from katana_common.messages import to_seconds
from katana_common.qos import CLOCK_QOS
from katana_interfaces.action import PickAndPlace
from katana_interfaces.msg import BlockArray
from rclpy.qos import DurabilityPolicy, QoSProfile
from rosgraph_msgs.msg import Clock

EXPECTED_TOPICS = {
    "/camera/image_raw": "sensor_msgs/msg/Image",
    "/camera/camera_info": "sensor_msgs/msg/CameraInfo",
    "/joint_states": "sensor_msgs/msg/JointState",
    "/clock": "rosgraph_msgs/msg/Clock",
    "/sim/ground_truth": "katana_interfaces/msg/BlockArray",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/tf_static": "tf2_msgs/msg/TFMessage",
    "/robot_description": "std_msgs/msg/String",
}
EXPECTED_ACTIONS = {
    "/arm_controller/follow_joint_trajectory": "control_msgs/action/FollowJointTrajectory",
    "/gripper_controller/gripper_command": "control_msgs/action/GripperCommand",
    "/pick_and_place": "katana_interfaces/action/PickAndPlace",
}
EXPECTED_SERVICES = {"/sim_node/reset_world": "katana_interfaces/srv/ResetWorld"}


def _sim_params(**sim):
    params = load_params(default_params_files("sim"))
    params["sim_node"].update(sim)
    return params


def _red_on_blue(blocks: dict) -> PickAndPlace.Goal:
    """Pick the red block and place it squarely on the blue one (ground-truth Blocks by id)."""
    red, blue = blocks["red"], blocks["blue"]
    goal = PickAndPlace.Goal(block_id="red", pick=red.pose, block_size=red.size)
    goal.place.position.x = blue.pose.position.x
    goal.place.position.y = blue.pose.position.y
    goal.place.position.z = blue.pose.position.z + blue.size.z
    goal.place.orientation = blue.pose.orientation
    return goal


def test_graph_matches_design_and_stacks_a_block(ros_graph, graph_offers):
    g = ros_graph
    g.add(*build_nodes("sim", _sim_params(real_time_factor=0.0, seed=3), g.context,
                       layers=["arm"]))
    probe = g.node("graph_test_probe")
    truth: dict = {}
    probe.create_subscription(
        BlockArray, "sim/ground_truth", lambda msg: truth.update(last=msg),
        QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))

    names = g.wait_for(lambda: {"sim_node", "pick_place_executor"}
                       <= set(probe.get_node_names()) and set(probe.get_node_names()))
    assert {"sim_node", "pick_place_executor"} <= names

    graph_offers(g, probe, "topics", EXPECTED_TOPICS)
    graph_offers(g, probe, "actions", EXPECTED_ACTIONS)
    graph_offers(g, probe, "services", EXPECTED_SERVICES)
    # who subscribes joint_states: the executor (it reads the arm only through it and actions)
    subs = {i.node_name for i in probe.get_subscriptions_info_by_topic("/joint_states")}
    assert "pick_place_executor" in subs

    blocks = {b.id: b for b in g.wait_for(lambda: truth.get("last")).blocks}
    blue = blocks["blue"]
    goal = _red_on_blue(blocks)
    client = ActionClient(probe, PickAndPlace, "pick_and_place")
    assert client.wait_for_server(timeout_sec=5.0)
    phases: list[str] = []
    handle = g.result(client.send_goal_async(
        goal, feedback_callback=lambda fb: phases.append(fb.feedback.phase)))
    assert handle.accepted
    res = g.result(handle.get_result_async(), timeout=60.0)
    assert res.result.success, res.result.message
    assert "approach" in phases and "park" in phases

    def stacked():
        msg = truth.get("last")
        blocks = {b.id: b for b in msg.blocks} if msg else {}
        return blocks and blocks["red"].level == 2 and not blocks["blue"].on_top and blocks

    blocks = g.wait_for(stacked, timeout=20.0)
    assert math.hypot(blocks["red"].pose.position.x - blue.pose.position.x,
                      blocks["red"].pose.position.y - blue.pose.position.y) < 0.005

    # a block id that does not exist, at a spot where no block lies: over at the grasp
    ghost = PickAndPlace.Goal(block_id="ghost", pick=blocks["green"].pose,
                              block_size=blocks["green"].size, place=goal.place)
    ghost.pick.position.x, ghost.pick.position.y = next(
        (x, y) for x, y in [(0.16, 0.09), (0.16, -0.09), (0.24, 0.12), (0.24, -0.12)]
        if all(math.hypot(b.pose.position.x - x, b.pose.position.y - y) > 0.06
               for b in blocks.values()))
    phases.clear()
    handle = g.result(client.send_goal_async(
        ghost, feedback_callback=lambda fb: phases.append(fb.feedback.phase)))
    res = g.result(handle.get_result_async(), timeout=60.0)
    assert res.result.error_code == PickAndPlace.Result.GRASP_MISSED, res.result.message
    assert "grasp" in phases and not {"lift", "carry", "lower", "release"} & set(phases)


def test_block_memory_follows_a_hand_sent_pick_and_place_on_sim_time(ros_graph):
    """No curiosity node: block memory learns the new levels from the detections alone, and
    every node of the graph runs on the simulation's clock."""
    g = ros_graph
    nodes = build_nodes("sim", _sim_params(real_time_factor=0.0, seed=3), g.context,
                        layers=["arm", "perception"])
    g.add(*nodes)
    assert all(n.get_parameter("use_sim_time").value for n in nodes)
    probe = g.node("memory_test_probe")
    truth: dict = {}
    memory: list[BlockArray] = []
    clock: list = []
    state_qos = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    probe.create_subscription(BlockArray, "sim/ground_truth",
                              lambda msg: truth.update(last=msg), state_qos)
    probe.create_subscription(BlockArray, "memory/blocks", memory.append, state_qos)
    probe.create_subscription(Clock, "/clock", lambda m: clock.append(m.clock), CLOCK_QOS)
    g.wait_for(lambda: truth.get("last") and memory and len(memory[-1].blocks) == 4
               and clock, timeout=60.0)
    # memory/blocks carries the image's sim-time stamp, within a second of /clock
    stamp = to_seconds(memory[-1].header.stamp)
    assert 0.0 < stamp and abs(to_seconds(clock[-1]) - stamp) < 1.0
    goal = _red_on_blue({b.id: b for b in truth["last"].blocks})
    client = ActionClient(probe, PickAndPlace, "pick_and_place")
    assert client.wait_for_server(timeout_sec=5.0)
    handle = g.result(client.send_goal_async(goal))
    res = g.result(handle.get_result_async(), timeout=60.0)
    assert res.result.success, res.result.message

    def levels(msg):
        return {b.id: b.level for b in msg.blocks}

    want = g.wait_for(lambda: truth["last"].blocks and levels(truth["last"])["red"] == 2
                      and levels(truth["last"]), timeout=20.0)
    got = g.wait_for(lambda: memory and levels(memory[-1]) == want and levels(memory[-1]),
                     timeout=20.0)
    assert got == want and got["red"] == 2
    on_blue = {b.id: b for b in memory[-1].blocks}
    assert not on_blue["blue"].on_top and on_blue["red"].on_top
    for msg in memory:
        for b in msg.blocks:
            p = b.pose.position
            assert all(math.isfinite(v) for v in (p.x, p.y, p.z, b.yaw))
