"""build_hardware_nodes: the hardware backend against the emulator and a SUBSTITUTE camera."""

import time

import pytest
import rclpy
from katana_common.executor import MultiThreadedExecutor
from katana_common.params import ParameterError
from katana_driver.bringup import build_hardware_nodes, load_hardware_params
from rclpy.context import Context
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image, JointState

pytestmark = pytest.mark.timeout(60)


def test_config_yaml_defaults_and_overlay():
    merged = load_hardware_params({"katana_driver_node": {"ros__parameters": {"port": 6000}}})
    assert merged["katana_driver_node"]["port"] == 6000
    assert merged["katana_driver_node"]["host"] == "192.168.1.1"
    assert merged["camera_node"]["device"] == "/dev/video0"


def test_hardware_nodes_run_against_the_emulator(make_emulator):
    emulator = make_emulator()
    host, port = emulator.address
    ctx = Context()
    rclpy.init(context=ctx)
    nodes = build_hardware_nodes(
        {
            "katana_driver_node": {"host": host, "port": port},
            "camera_node": {"device": "substitute", "rate": 30.0},
        },
        ctx,
        namespace="lab",
    )
    probe = Node("bringup_probe", namespace="lab", context=ctx)
    states, images = [], []
    probe.create_subscription(JointState, "joint_states", states.append, 10)
    probe.create_subscription(Image, "camera/image_raw", images.append, qos_profile_sensor_data)
    executor = MultiThreadedExecutor(num_threads=4, context=ctx)
    for node in [*nodes, probe]:
        executor.add_node(node)
    try:
        deadline = time.monotonic() + 15.0
        while time.monotonic() < deadline and not (states and images and nodes[0].ready):
            executor.spin_once(timeout_sec=0.05)
        assert states and images and nodes[0].ready
        names = dict(probe.get_topic_names_and_types())
        assert "/lab/arm_controller/follow_joint_trajectory/_action/status" in names
        assert "/lab/camera/camera_info" in names
        assert {n.get_name() for n in nodes} == {"katana_driver_node", "camera_node"}
    finally:
        executor.shutdown()
        for node in [*nodes, probe]:
            node.destroy_node()
        rclpy.shutdown(context=ctx)


def test_a_bad_value_names_the_parameter():
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        with pytest.raises(ParameterError, match="poll_rate"):
            build_hardware_nodes({"katana_driver_node": {"poll_rate": 500.0}}, ctx)
    finally:
        rclpy.shutdown(context=ctx)
