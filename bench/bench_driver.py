"""Driver speed and safety against the katana-emulator on loopback.

request_ms: median round trip of a position read (N 3 0) over TCP, framing and CRC included;
state_hz: joint_states messages per second that katana_driver_node delivers to a subscriber
(idle, and while a trajectory runs: status flags are read every poll then), from the
messages' own stamps (the poll times) and from their arrival. Targets: request_ms < 1 (the
driver's own overhead) and state_hz >= 25 (the configured poll_rate). The real arm takes
about 40 ms a request; these numbers say nothing about it.

faults: one trajectory goal under each of the emulator's fault knobs (katana_driver.testing,
shipped timeout 0.5 s and 3 retries): segments the controller got twice, the largest per-10 ms
joint step over the joint's speed limit, how the goal ended and whether the next goal (fault
cleared) succeeded. Targets: 0 duplicated segments and max_speed_ratio <= 1.05 for every fault.
"""

from __future__ import annotations

import json
import os
import signal
import statistics
import subprocess
import sys
import time

from control_msgs.action import FollowJointTrajectory
from katana_bringup.in_process import InProcessGraph
from katana_common.action_client import ActionClient
from katana_common.messages import to_seconds
from katana_common.testing import private_ros_env
from katana_driver.core import protocol
from katana_driver.core.client import KatanaClient
from katana_driver.core.transport import SerialTransport, TcpTransport
from katana_driver.katana_driver_node import KatanaDriverNode
from katana_driver.testing import FAULTS, POSE_B, FaultBench, trajectory
from katana_emulator.emulator import Faults, KatanaEmulator, KatanaModel
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")


def _request_times(client, n: int) -> list[float]:
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        client.read_positions()
        times.append((time.perf_counter() - t0) * 1e3)
    return times


def _rate(times: list[float]) -> float:
    return (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 else 0.0


def _state_rates(host: str, port: int) -> dict:
    """joint_states rates, idle and during a 4 s trajectory, with the shipped poll_rate."""
    with InProcessGraph(threads=4) as g:
        node = KatanaDriverNode(node_name="bench_katana_driver", context=g.context,
                                parameter_overrides=[Parameter("host", value=host),
                                                     Parameter("port", value=port)])
        g.add(node)
        probe = g.node("bench_driver_probe")
        got: list[tuple[float, float]] = []  # (header stamp, arrival)
        probe.create_subscription(
            JointState, "joint_states",
            lambda m: got.append((to_seconds(m.header.stamp), time.monotonic())), 100)
        arm = ActionClient(probe, FollowJointTrajectory, "arm_controller/follow_joint_trajectory")
        deadline = time.monotonic() + 15.0
        while time.monotonic() < deadline and not (node.ready and arm.server_is_ready()):
            time.sleep(0.05)
        time.sleep(0.5)
        got.clear()
        time.sleep(4.0)
        idle = list(got)
        got.clear()
        done = arm.send_goal_async(trajectory(POSE_B, 4.0))
        time.sleep(4.0)
        moving = list(got)
        out = {
            "state_hz": round(_rate([a for _, a in idle]), 2),
            "state_hz_from_stamps": round(_rate([s for s, _ in idle]), 2),
            "state_hz_moving": round(_rate([a for _, a in moving]), 2),
            "state_hz_moving_from_stamps": round(_rate([s for s, _ in moving]), 2),
        }
        del done
    return out


def _shutdown_times() -> dict:
    """Seconds from SIGINT / SIGTERM to the exit of a separate driver process (idle, and mid
    trajectory) and of a camera_node process. Target: <= 2 s (docs/hardware.md: a signal ends
    the node within 2 s)."""
    env = private_ros_env(PYTHONUNBUFFERED="1")
    goal = ("import rclpy\nfrom katana_driver.testing import POSE_B, trajectory\n"
            "from control_msgs.action import FollowJointTrajectory as F\n"
            "from katana_common.action_client import ActionClient\nrclpy.init()\n"
            "n = rclpy.create_node('bench_goal')\n"
            "c = ActionClient(n, F, 'arm_controller/follow_joint_trajectory')\n"
            "c.wait_for_server(timeout_sec=20.0)\nc.send_goal_async(trajectory(POSE_B, 20.0))\n"
            "rclpy.spin(n)\n")

    def one(args, ready, sig, moving=None) -> float:
        proc = subprocess.Popen([sys.executable, *args], env=env, text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        for line in proc.stdout:
            if ready in line:
                break
        sender = None
        if moving is not None:
            sender = subprocess.Popen([sys.executable, "-c", goal], env=env)
            deadline = time.monotonic() + 30.0
            while moving() and time.monotonic() < deadline:
                time.sleep(0.02)
        t0 = time.monotonic()
        proc.send_signal(sig)
        try:
            proc.wait(timeout=30.0)
        finally:
            if sender is not None:
                sender.kill()
                sender.wait()
        return round(time.monotonic() - t0, 3)

    out = {}
    for name, sig in (("SIGINT", signal.SIGINT), ("SIGTERM", signal.SIGTERM)):
        emulator = KatanaEmulator(KatanaModel(calibrated=True), Faults())
        host, port = emulator.serve_tcp("127.0.0.1", 0)
        driver = ["-m", "katana_driver.katana_driver_node", "--ros-args", "-p",
                  f"host:={host}", "-p", f"port:={port}"]
        try:
            out[f"driver_idle_{name}"] = one(driver, "arm ready", sig)
            out[f"driver_mid_trajectory_{name}"] = one(
                driver, "arm ready", sig, moving=lambda e=emulator: e.model.statuses()[0] != 24)
        finally:
            emulator.stop()
        out[f"camera_{name}"] = one(["-m", "katana_camera.camera_node", "--ros-args", "-p",
                                     "device:=substitute"], "capturing from", sig)
    return out


def _faults() -> dict:
    results = {}
    for name in FAULTS:
        bench = FaultBench(timeout_s=0.5, retries=3)
        try:
            results[name] = bench.run_case(name, legs=3).as_dict()
        finally:
            bench.close()
    return results


def run() -> dict:
    emulator = KatanaEmulator(KatanaModel(calibrated=True))
    host, port = emulator.serve_tcp("127.0.0.1", 0)
    device = emulator.serve_pty()
    try:
        tcp = KatanaClient(TcpTransport(host, port, timeout=0.5))
        tcp.connect()
        _request_times(tcp, 50)  # warm-up
        tcp_ms = _request_times(tcp, 2000)
        tcp.close()
        serial = KatanaClient(SerialTransport(device, timeout=0.5))
        serial.connect()
        serial_ms = _request_times(serial, 300)
        serial.close()

        payload = protocol.read_positions().payload
        t0 = time.perf_counter()
        for _ in range(2000):
            protocol.frame_reply(emulator.model.handle(payload))
        emulator_ms = (time.perf_counter() - t0) / 2000 * 1e3

        state = _state_rates(host, port)
    finally:
        emulator.stop()
    tcp_sorted = sorted(tcp_ms)
    return {
        "request_ms": round(statistics.median(tcp_ms), 4),
        "request_p95_ms": round(tcp_sorted[int(0.95 * len(tcp_sorted))], 4),
        "serial_request_ms": round(statistics.median(serial_ms), 4),
        "emulator_handle_ms": round(emulator_ms, 4),
        **state,
        "poll_rate_hz": 25.0,
        "shutdown_s": _shutdown_times(),
        "faults": _faults(),
        "targets": {"request_ms": "< 1", "state_hz": ">= 25", "duplicated_segments": "0",
                    "max_speed_ratio": "<= 1.05", "shutdown_s": "<= 2"},
        "note": "against the katana-emulator on loopback, latency off; not the real arm",
    }


if __name__ == "__main__":
    print(json.dumps(run(), indent=2))
