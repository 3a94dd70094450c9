"""backend:=hardware: the whole graph starts against the protocol EMULATOR (not an arm) and a
SUBSTITUTE camera, with the same node, topic and action names as the simulated graph; and the
documented dry run (the emulator's console script, then `katana-run --backend hardware` with
the shipped YAML overriding only the emulator's host and port and the substitute camera) runs
the curiosity loop."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import time

import pytest
from katana_bringup.run import build_nodes, default_params_files, load_params
from katana_common.testing import private_ros_env, stop_process, wait_for_output
from katana_description import models
from katana_emulator.emulator import Faults, KatanaEmulator, KatanaModel
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


@pytest.mark.timeout(600)
def test_dry_run_from_the_command_line_runs_experiments_against_the_emulator(tmp_path):
    """The dry run of docs/hardware.md section 3, as a user runs it: the emulator started by its
    console script with command-line options only (a 4 cm block in the gripper, so that grasps
    hold; motion 20 times faster), then `katana-run --backend hardware` with the shipped YAML
    overriding only the emulator's host and port and the substitute camera; separate processes.
    At least five experiments reach the experience log, and not every grasp missed."""
    env = private_ros_env()
    emulator = subprocess.Popen(
        [shutil.which("katana-emulator") or "katana-emulator", "--port", "0",
         "--time-scale", "20", "--block-width-m", str(models.BLOCK_SIZE[0])],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env)
    run = None
    try:
        found = wait_for_output(emulator.stdout, r"listening on tcp ([\d.]+):(\d+)", 20.0)
        assert found, "the emulator did not say where it listens"
        host, port = found.group(1), int(found.group(2))
        overlay = tmp_path / "emulator.yaml"
        overlay.write_text(
            "katana_driver_node:\n  ros__parameters:\n"
            f"    host: \"{host}\"\n    port: {port}\n"
            "camera_node:\n  ros__parameters:\n    device: \"substitute\"\n")
        log = tmp_path / "run" / "katana-run.log"
        log.parent.mkdir()
        with open(log, "w") as out:
            run = subprocess.Popen(
                [sys.executable, "-m", "katana_bringup.run", "--backend", "hardware",
                 "--params", str(overlay)], cwd=tmp_path / "run", env=env, stdout=out,
                stderr=subprocess.STDOUT)
        experiences = tmp_path / "run" / "runs" / "robot" / "experience.jsonl"
        deadline = time.monotonic() + 480
        lines: list[str] = []
        while len(lines) < 5:
            assert run.poll() is None, log.read_text()[-4000:]
            assert emulator.poll() is None, "the emulator stopped"
            assert time.monotonic() < deadline, (
                f"{len(lines)} experiments in 480 s\n" + log.read_text()[-4000:])
            if experiences.exists():  # complete lines only: each ends with its newline
                lines = experiences.read_text().splitlines(keepends=True)
                lines = [line for line in lines if line.endswith("\n")]
            time.sleep(1.0)
        stop_process(run, signal.SIGINT)
        assert run.returncode == 0, log.read_text()[-4000:]
        text = log.read_text()
        assert "Traceback" not in text
        records = [json.loads(line) for line in lines]
        assert [r["index"] for r in records] == list(range(len(records)))
        # a grasp that missed is retried (attempts > 1); with the block in the gripper the
        # first attempt holds
        assert all(r["attempts"] == 1 for r in records), records
    finally:
        for proc in (run, emulator):
            if proc is not None and proc.poll() is None:
                stop_process(proc, signal.SIGINT, timeout_s=10.0)
