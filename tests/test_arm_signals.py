"""SIGINT and SIGTERM end sim_node and pick_place_executor within 2 s, idle or mid-motion, with
exit code 0 and no traceback; both run as separate processes, as `ros2 launch` starts them, and
the executor works under use_sim_time with the sim's /clock."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest
from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory
from geometry_msgs.msg import Pose
from katana_common.action_client import ActionClient
from katana_common.testing import probe_node, spin_until, stop_process, use_private_domain
from katana_description import models as m
from katana_interfaces.action import PickAndPlace
from rcl_interfaces.srv import GetParameters
from trajectory_msgs.msg import JointTrajectoryPoint

pytestmark = pytest.mark.timeout(300)
NODE_LIMIT_S = 2.0  # every node ends within 2 s of the signal


@pytest.fixture
def probe(monkeypatch):
    use_private_domain(monkeypatch)
    procs: list[subprocess.Popen] = []
    with probe_node("arm_signal_probe") as (node, ex):
        yield node, ex, procs
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()


def _start(procs, module: str, *params: str) -> subprocess.Popen:
    args = [sys.executable, "-m", module, "--ros-args", "-p", "use_sim_time:=true"]
    for p in params:
        args += ["-p", p]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    procs.append(proc)
    return proc


def _spin_until(ex, cond, what: str, proc: subprocess.Popen, timeout_s: float = 90.0) -> None:
    """Spin until `cond` holds; fail with `what` at the deadline, or with the stderr of `proc`
    as soon as it exits."""

    def alive_and_cond():
        assert proc.poll() is None, proc.communicate()[1]
        return cond()

    assert spin_until(ex, alive_and_cond, timeout_s), what


def _spinning(node, ex, proc, name: str) -> None:
    """Wait until `name` answers a service call: its executor spins (a signal before that
    tests katana_common's start-up, not this node)."""
    client = node.create_client(GetParameters, f"{name}/get_parameters")
    _spin_until(ex, client.service_is_ready, f"{name} has no parameter service", proc)
    future = client.call_async(GetParameters.Request(names=["use_sim_time"]))
    _spin_until(ex, future.done, f"{name} does not answer", proc)
    assert future.result().values[0].bool_value  # runs with use_sim_time


def _stop(proc, sig) -> float:
    """Signal `proc`; it must exit with code 0 and no traceback. Returns how long it took."""
    took, out, err = stop_process(proc, sig)
    assert proc.returncode == 0, err
    assert "Traceback" not in out + err, err
    return took


def _long_trajectory() -> FollowJointTrajectory.Goal:
    goal = FollowJointTrajectory.Goal()
    goal.trajectory.joint_names = list(m.ARM_JOINTS)
    goal.trajectory.points = [JointTrajectoryPoint(positions=[0.5, 1.2, -1.5, 1.2, 0.5],
                                                   time_from_start=Duration(sec=8))]
    return goal


SIGNALS = pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM],
                                  ids=["SIGINT", "SIGTERM"])


@SIGNALS
@pytest.mark.parametrize("moving", [False, True], ids=["idle", "mid-motion"])
def test_a_signal_ends_sim_node_cleanly(probe, sig, moving):
    node, ex, procs = probe
    sim = _start(procs, "katana_sim.sim_node", "real_time_factor:=1.0", "camera_rate:=5.0")
    client = ActionClient(node, FollowJointTrajectory, "arm_controller/follow_joint_trajectory")
    _spin_until(ex, client.server_is_ready, "sim_node never served its arm action", sim)
    _spinning(node, ex, sim, "sim_node")
    if moving:  # signal while the arm follows an 8 s trajectory
        feedback: list = []
        sent = client.send_goal_async(_long_trajectory(), feedback_callback=feedback.append)
        _spin_until(ex, lambda: len(feedback) >= 2, "no feedback: the arm is not moving", sim)
        assert sent.result().accepted
    took = _stop(sim, sig)
    assert took <= NODE_LIMIT_S, f"sim_node took {took:.2f} s to stop"


def _pick_goal() -> PickAndPlace.Goal:
    goal = PickAndPlace.Goal(block_id="any")
    goal.pick, goal.place = Pose(), Pose()
    goal.pick.position.x, goal.pick.position.z, goal.pick.orientation.w = 0.2, 0.015, 1.0
    goal.place.position.x, goal.place.position.y = 0.2, 0.1
    goal.place.position.z, goal.place.orientation.w = 0.015, 1.0
    goal.block_size.x, goal.block_size.y, goal.block_size.z = m.BLOCK_SIZE
    return goal


@SIGNALS
@pytest.mark.parametrize("moving", [False, True], ids=["idle", "mid-motion"])
def test_a_signal_ends_pick_place_executor_cleanly(probe, sig, moving):
    node, ex, procs = probe
    sim = _start(procs, "katana_sim.sim_node", "real_time_factor:=1.0", "camera_rate:=0.0")
    executor = _start(procs, "katana_manipulation.pick_place_executor")
    client = ActionClient(node, PickAndPlace, "pick_and_place")
    _spin_until(ex, client.server_is_ready, "no pick_and_place server", executor)
    _spinning(node, ex, sim, "sim_node")
    _spinning(node, ex, executor, "pick_place_executor")
    phases: list[str] = []
    if moving:  # signal while the arm approaches the block (the executor waits on the sim)
        client.send_goal_async(_pick_goal(),
                               feedback_callback=lambda f: phases.append(f.feedback.phase))
        _spin_until(ex, lambda: "approach" in phases, "the executor never moved the arm",
                    executor)
    took = _stop(executor, sig)
    assert took <= NODE_LIMIT_S, f"pick_place_executor took {took:.2f} s to stop"
    took = _stop(sim, sig)
    assert took <= NODE_LIMIT_S, f"sim_node took {took:.2f} s to stop"
