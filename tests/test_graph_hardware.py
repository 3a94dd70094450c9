"""backend:=hardware: the whole graph starts against the protocol EMULATOR (not an arm) and a
SUBSTITUTE camera, with the same node, topic and action names as the simulated graph; and
`katana-run --backend hardware` with the shipped YAML (overriding only the emulator's host and
port and the substitute camera) runs the curiosity loop."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest
from katana_bringup.run import build_nodes, default_params_files, load_params
from katana_common.testing import private_ros_env
from katana_description import models
from katana_driver.core.encoders import EncoderModel
from katana_driver.emulator import Faults, KatanaEmulator, KatanaModel
from katana_interfaces.msg import LearnerState
from rclpy.qos import DurabilityPolicy, QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import Image, JointState

pytestmark = pytest.mark.timeout(120)

EXPECTED_NODES = {"katana_driver_node", "camera_node", "frame_publisher", "pick_place_executor",
                  "perception_node", "block_memory_node", "fovea_node", "curiosity_node"}
EXPECTED_ACTIONS = {
    "/arm_controller/follow_joint_trajectory": "control_msgs/action/FollowJointTrajectory",
    "/gripper_controller/gripper_command": "control_msgs/action/GripperCommand",
    "/pick_and_place": "katana_interfaces/action/PickAndPlace",
}
EXPECTED_SERVICES = {
    "/katana_driver_node/reset_world": "katana_interfaces/srv/ResetWorld",
    "/katana_driver_node/set_motors": "katana_interfaces/srv/SetMotors",
    "/fovea/observe": "katana_interfaces/srv/ObserveSetting",
    "/fovea/find_placement": "katana_interfaces/srv/FindPlacement",
    "/perception/judge_placement": "katana_interfaces/srv/JudgePlacement",
}


@pytest.fixture
def emulator():
    emu = KatanaEmulator(KatanaModel(variant="6M180", time_scale=20.0, calibration_s=0.2),
                         Faults())
    emu.serve_tcp("127.0.0.1", 0)
    try:
        yield emu
    finally:
        emu.stop()


def test_hardware_graph_starts_against_the_emulator_and_a_substitute_camera(
        ros_graph, graph_offers, emulator, tmp_path):
    host, port = emulator.address
    params = load_params(default_params_files("hardware"))
    params["katana_driver_node"] = {"host": host, "port": port}
    params["camera_node"] = {"device": "substitute", "rate": 10.0}
    assert params["/**"]["use_sim_time"] is False  # hardware: wall time for every node
    params["curiosity_node"].update(run_dir=str(tmp_path), max_experiments=1,
                                    service_timeout_s=2.0, blocks_timeout_s=2.0)
    g = ros_graph
    nodes = build_nodes("hardware", params, g.context)
    assert {n.get_name() for n in nodes} == EXPECTED_NODES
    g.add(*nodes)
    probe = g.node("hardware_graph_probe")
    joints: list[JointState] = []
    images: list[Image] = []
    learner: list[LearnerState] = []
    probe.create_subscription(JointState, "joint_states", joints.append, 10)
    probe.create_subscription(Image, "camera/image_raw", images.append, qos_profile_sensor_data)
    probe.create_subscription(LearnerState, "curiosity/learner_state", learner.append,
                              QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))

    g.wait_for(lambda: EXPECTED_NODES <= set(probe.get_node_names()), timeout=20.0)
    g.wait_for(lambda: joints and images and learner, timeout=30.0)
    assert len(joints[-1].name) == 7, "five arm joints and two fingers, as from the sim"
    assert (images[-1].width, images[-1].height, images[-1].encoding) == (640, 480, "rgb8")
    graph_offers(g, probe, "actions", EXPECTED_ACTIONS)
    graph_offers(g, probe, "services", EXPECTED_SERVICES)
    # the emulated controller is being talked to: the driver calibrated it
    driver = next(n for n in nodes if n.get_name() == "katana_driver_node")
    g.wait_for(lambda: driver.ready, timeout=30.0)


@pytest.mark.timeout(900)
def test_katana_run_hardware_runs_the_curiosity_loop_against_the_emulator(emulator, tmp_path):
    # The emulator has no blocks: its gripper stalls where a 4 cm block would hold the fingers,
    # so that a grasp reads as holding one (the substitute camera's squares do not move).
    block_angle = models.finger_angle_for_opening(0.04)
    emulator.model.gripper_stall_at = int(EncoderModel.gripper_angle_to_encoder(block_angle))
    host, port = emulator.address
    overlay = tmp_path / "emulator.yaml"
    overlay.write_text(
        "katana_driver_node:\n  ros__parameters:\n"
        f"    host: \"{host}\"\n    port: {port}\n"
        "camera_node:\n  ros__parameters:\n    device: \"substitute\"\n")
    env = private_ros_env()
    log = tmp_path / "run" / "katana-run.log"
    log.parent.mkdir()
    with open(log, "w") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "katana_bringup.run", "--backend", "hardware",
             "--params", str(overlay)], cwd=tmp_path / "run", env=env, stdout=out,
            stderr=subprocess.STDOUT)
    experiences = tmp_path / "run" / "runs" / "robot" / "experience.jsonl"
    deadline = time.monotonic() + 780
    done = 0
    try:
        while done < 20:
            assert proc.poll() is None, log.read_text()[-4000:]
            assert time.monotonic() < deadline, (
                f"{done} experiments in 780 s\n" + log.read_text()[-4000:])
            if experiences.exists():
                done = experiences.read_text().count("\n")  # one complete line each
            time.sleep(1.0)
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, log.read_text()[-4000:]
    assert "Traceback" not in log.read_text()
