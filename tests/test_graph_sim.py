"""The simulated graph built by katana-run's build_nodes, seen through rclpy: names and types of
DESIGN.md's node graph, and one stacking pick-and-place through the action."""

from __future__ import annotations

import math

from katana_bringup.run import build_nodes, default_params_files, load_params
from katana_interfaces.action import PickAndPlace
from katana_interfaces.msg import BlockArray
from rclpy.action import ActionClient, get_action_names_and_types
from rclpy.qos import DurabilityPolicy, QoSProfile

EXPECTED_TOPICS = {
    "/camera/image_raw": "sensor_msgs/msg/Image",
    "/camera/camera_info": "sensor_msgs/msg/CameraInfo",
    "/joint_states": "sensor_msgs/msg/JointState",
    "/clock": "rosgraph_msgs/msg/Clock",
    "/sim/ground_truth": "katana_interfaces/msg/BlockArray",
}
EXPECTED_ACTIONS = {
    "/arm_controller/follow_joint_trajectory": "katana_interfaces/action/FollowJointTrajectory",
    "/gripper_controller/gripper_command": "katana_interfaces/action/GripperCommand",
    "/pick_and_place": "katana_interfaces/action/PickAndPlace",
}
EXPECTED_SERVICES = {"/sim_node/reset_world": "katana_interfaces/srv/ResetWorld"}


def _sim_params(**sim):
    params = load_params(default_params_files("sim"))
    params["sim_node"].update(sim)
    return params


def test_graph_matches_design_and_stacks_a_block(ros_graph):
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

    def topics():
        found = dict(probe.get_topic_names_and_types())
        return all(t in found for t in EXPECTED_TOPICS) and found

    found = g.wait_for(topics)
    for topic, kind in EXPECTED_TOPICS.items():
        assert found[topic] == [kind], topic
    actions = g.wait_for(lambda: dict(get_action_names_and_types(probe)).keys()
                         >= EXPECTED_ACTIONS.keys() and dict(get_action_names_and_types(probe)))
    for name, kind in EXPECTED_ACTIONS.items():
        assert actions[name] == [kind], name
    services = g.wait_for(lambda: dict(probe.get_service_names_and_types()).keys()
                          >= EXPECTED_SERVICES.keys() and dict(probe.get_service_names_and_types()))
    for name, kind in EXPECTED_SERVICES.items():
        assert services[name] == [kind]
    # who subscribes joint_states: the executor (it reads the arm only through it and actions)
    subs = {i.node_name for i in probe.get_subscriptions_info_by_topic("/joint_states")}
    assert "pick_place_executor" in subs

    blocks = {b.id: b for b in g.wait_for(lambda: truth.get("last")).blocks}
    red, blue = blocks["red"], blocks["blue"]
    goal = PickAndPlace.Goal(block_id="red", pick=red.pose, block_size=red.size)
    goal.place.position.x = blue.pose.position.x
    goal.place.position.y = blue.pose.position.y
    goal.place.position.z = blue.pose.position.z + blue.size.z
    goal.place.orientation = blue.pose.orientation
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
