"""SIGINT and SIGTERM end katana_driver_node (a separate process, as ros2 launch starts it)
cleanly, with exit code 0 and no traceback: idle, and in the middle of a trajectory goal, after
which the arm holds. How fast (within 2 s, docs/hardware.md) is measured by bench/bench_driver.py
(shutdown_s); here a generous bound only tells a hang from a slow machine."""

import signal
import subprocess
import sys
import threading
import time

import pytest
from katana_common.testing import private_ros_env

pytestmark = pytest.mark.timeout(60)
HANG_S = 15.0  # no timed assert: a node that has not ended by then hangs


def _env():
    return private_ros_env(PYTHONUNBUFFERED="1")


class NodeProcess:
    """The node in its own process; its log collected by a thread."""

    def __init__(self, args):
        self.proc = subprocess.Popen([sys.executable, *args], env=_env(), text=True,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        self.lines: list[str] = []
        self.seen = threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stdout:
            with self.seen:
                self.lines.append(line)
                self.seen.notify_all()

    def wait_for(self, text, limit_s=20.0):
        deadline = time.monotonic() + limit_s
        with self.seen:
            while not any(text in line for line in self.lines):
                if time.monotonic() > deadline or self.proc.poll() is not None:
                    return False
                self.seen.wait(0.1)
        return True

    def stop(self, sig):
        self.proc.send_signal(sig)
        try:
            return self.proc.wait(timeout=HANG_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            return None

    @property
    def log(self):
        time.sleep(0.1)  # the reader thread drains the pipe after the exit
        return "".join(self.lines)


def driver(emulator, *extra):
    host, port = emulator.address
    return NodeProcess(["-m", "katana_driver.katana_driver_node", "--ros-args",
                        "-p", f"host:={host}", "-p", f"port:={port}", *extra])


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_ends_the_idle_driver_cleanly(make_emulator, sig):
    node = driver(make_emulator(calibrated=True))
    assert node.wait_for("arm ready"), node.log
    code = node.stop(sig)
    log = node.log
    assert code == 0, log
    assert "Traceback" not in log


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_mid_trajectory_ends_the_driver_and_the_arm_holds(make_emulator, sig):
    """A goal of 30 s (a long way, slowly) is running when the signal comes."""
    emulator = make_emulator(calibrated=True)
    node = driver(emulator)
    assert node.wait_for("arm ready"), node.log
    goal = subprocess.Popen(
        [sys.executable, "-c", _SEND_GOAL], env=_env(), text=True,
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        moving = False
        for _ in range(300):
            if emulator.model.statuses()[0] == 24:  # moving
                moving = True
                break
            time.sleep(0.05)
        assert moving, node.log
        code = node.stop(sig)
        log = node.log
        assert code == 0, log
        assert "Traceback" not in log
        assert emulator.model.statuses()[:5] == [8] * 5  # holding: frozen before the exit
    finally:
        goal.kill()
        goal.wait()


_SEND_GOAL = """
import rclpy
from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory
from katana_common.action_client import ActionClient
from trajectory_msgs.msg import JointTrajectoryPoint
rclpy.init()
node = rclpy.create_node("signal_test_goal_sender")
client = ActionClient(node, FollowJointTrajectory, "arm_controller/follow_joint_trajectory")
client.wait_for_server(timeout_sec=20.0)
goal = FollowJointTrajectory.Goal()
goal.trajectory.joint_names = ["katana_motor1_pan_joint"]
goal.trajectory.points = [JointTrajectoryPoint(positions=[2.5], time_from_start=Duration(sec=30))]
future = client.send_goal_async(goal)
rclpy.spin_until_future_complete(node, future, timeout_sec=20.0)
rclpy.spin(node)
"""
