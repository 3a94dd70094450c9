"""curiosity_node in-process against fake fovea, judge, pick-and-place and memory servers: the
experiment loop, its log and checkpoint, waiting for the graph, saving and stopping."""

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from katana_common.executor import MultiThreadedExecutor
from katana_common.params import ParameterError
from katana_common.qos import DIAGNOSTICS_QOS
from katana_common.testing import private_domain_id
from katana_curiosity.core.robot_loop import POLICY_RESULTS, robot_bank
from katana_curiosity.core.run_record import CHECKPOINT_NAME, load_checkpoint, replay
from katana_curiosity.robot_environment import _code_name
from katana_interfaces.action import PickAndPlace
from katana_interfaces.srv import ResetWorld
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib
from curiosity_graph import FakeGraph, Graph, read_log, run_graph  # noqa: E402


def test_each_experiment_is_learned_once_logged_once_and_published(tmp_path) -> None:
    node, fake, states = run_graph(tmp_path, max_experiments=8)
    records = read_log(tmp_path)
    assert [r["index"] for r in records] == list(range(8))
    assert int(node.bank.examples.sum()) == 8
    assert len(fake.experiences) == 8 and len(fake.goals) == 8
    assert [e.index for e in fake.experiences] == list(range(8))
    # the learner is exactly what the log says
    bank = robot_bank(3, 6, 1.0, 0.1)
    replay(bank, node.log.records)
    np.testing.assert_allclose(bank.w, node.bank.w)
    for r in records:
        assert len(r["weights_before"]) == 7 and len(r["weights_after"]) == 7
        assert r["mode"] in ("query", "plan") and r["label"] in (-1, 1)
        assert r["moved_block"] not in r["instance"]["support_ids"]
    assert (tmp_path / "learner.npz").exists()
    assert states and states[-1].experiments == 8
    assert [h.height for h in states[-1].heights] == [0, 1, 2, 3]


def test_a_restart_resumes_without_losing_or_repeating_an_experiment(tmp_path) -> None:
    run_graph(tmp_path, max_experiments=5)
    first = read_log(tmp_path)
    # a crash mid-write leaves a partial line: it was never recorded; it is moved aside
    torn = b'{"index": 5, "state": 1, "act'
    with open(tmp_path / "experience.jsonl", "ab") as f:
        f.write(torn)
    node, fake, _ = run_graph(tmp_path, max_experiments=9)
    records = read_log(tmp_path)
    assert [r["index"] for r in records] == list(range(9))
    assert records[:5] == first
    assert [r["setting"] for r in records] == list(range(1, 10)), "i goes on over a resume"
    assert (tmp_path / "experience.jsonl.corrupt").read_bytes() == torn
    assert int(node.bank.examples.sum()) == 9
    assert len(fake.experiences) == 4, "only the new experiments are run"


def test_a_checkpoint_the_log_does_not_hold_is_kept_aside_not_overwritten(tmp_path) -> None:
    """A valid 30-experiment checkpoint beside an empty log: the run goes on from the log (0)
    and its new checkpoint never replaces the old one, which is kept under a name saying why."""
    run_graph(tmp_path, max_experiments=3)
    (tmp_path / "experience.jsonl").write_bytes(b"")
    before = (tmp_path / CHECKPOINT_NAME).read_bytes()
    node, _, _ = run_graph(tmp_path, max_experiments=2)
    aside = tmp_path / "learner.not-the-log-3-experiments.npz"
    assert aside.read_bytes() == before
    assert load_checkpoint(tmp_path / CHECKPOINT_NAME)[1] == 2 == len(read_log(tmp_path))


def test_diagnostics_report_the_run_as_the_log_has_it(tmp_path) -> None:
    """/diagnostics once a second: experiments, attempts dropped (by reason) and the pairs still
    unknown, each equal to what the log and a replay of it say."""
    with Graph(tmp_path, 5, {"unusable_first": 2}) as g:
        statuses: list = []
        g.probe.create_subscription(DiagnosticArray, "/diagnostics",
                                    lambda msg: statuses.extend(msg.status), DIAGNOSTICS_QOS)
        g.wait(g.node.finished.is_set, 30.0, "the experiment loop finishing")
        count = len(statuses)
        g.wait(lambda: len(statuses) > count, 5.0, "a status after the end")
    status = statuses[-1]
    assert status.name == "curiosity_node: experiments" and status.level == b"\x00"
    values = {kv.key: kv.value for kv in status.values}
    records = read_log(tmp_path)
    dropped = sum(sum(r["dropped_before"].values()) for r in records)
    assert values["experiments"] == str(len(records)) == "5"
    assert values["dropped"] == str(dropped) == "2"
    assert values["dropped_no_usable_instance"] == "2"
    bank = robot_bank(3, 6, 1.0, 0.1)
    replay(bank, g.node.log.records)
    planner = g.node.explorer.strategy.planner  # q1 plans: the pairs the arm can realise
    left = bank.unknown[:planner.top] & planner.feasible[:planner.top]
    assert values["unknown_pairs_left"] == str(int(np.count_nonzero(left)))
    assert float(values["experiments_per_min"]) > 0.0


def test_a_bad_line_stops_the_start_unless_quarantined(tmp_path) -> None:
    run_graph(tmp_path, max_experiments=4)
    path = tmp_path / "experience.jsonl"
    lines = path.read_bytes().splitlines(keepends=True)
    lines[1] = b'{"index": 1, "state": "two"}\n'
    path.write_bytes(b"".join(lines))
    context = rclpy.context.Context()
    rclpy.init(context=context)
    try:
        with pytest.raises(ParameterError, match="experience.jsonl:2: field 'action': is missing.*"
                           "quarantine_bad_lines"):
            Graph(tmp_path, 6)
    finally:
        rclpy.shutdown(context=context)
    assert path.read_bytes() == b"".join(lines), "a refusal changes nothing"
    with Graph(tmp_path, 6, quarantine_bad_lines=True) as g:
        assert len(g.node.log) == 3
        g.wait(g.node.finished.is_set, 30.0, "the experiment loop finishing")
    records = read_log(tmp_path)
    assert [r["index"] for r in records] == list(range(6))
    assert (tmp_path / "experience.jsonl.quarantine").read_bytes() == lines[1]
    assert (tmp_path / "experience.jsonl.before-quarantine").read_bytes() == b"".join(lines)


def test_bad_instances_and_missed_grasps_do_not_stop_the_run(tmp_path) -> None:
    node, fake, _ = run_graph(tmp_path, max_experiments=4, unusable_first=2, grasp_misses=1)
    records = read_log(tmp_path)
    assert len(records) == 4
    assert records[0]["attempts"] == 2, "a missed grasp is retried"
    assert records[0]["dropped_before"] == {"no_usable_instance": 2}
    assert [r["setting"] for r in records] == [3, 4, 5, 6], "the paper's i: drops included"
    assert all(r["dropped_before"] == {} for r in records[1:])
    assert fake.observations >= 6


def test_after_a_reset_the_next_look_waits_for_a_settled_frame_of_the_new_scene(
        tmp_path) -> None:
    """A reset that says from when its scene stands (ResetWorld's stamp) is followed by an
    observation only once the memory has published a frame of an image stamped at or after
    it with a settled frame: not one a fixed margin after the learner's own clock."""
    node, fake, _ = run_graph(tmp_path, max_experiments=2, unusable_first=2, reset_ahead_s=0.3)
    assert len(fake.reset_stamps_ns) == 2 and fake.observations >= 4
    for stood, (frame_ns, settled) in zip(fake.reset_stamps_ns, fake.seen_at_observe[1:],
                                          strict=False):
        assert frame_ns >= stood and settled >= 1, (frame_ns - stood, settled)
    # the reset moved the arm: every pick-and-place after it plans from joints stamped since
    after = [g.joint_states_after.sec * 10**9 + g.joint_states_after.nanosec for g in fake.goals]
    assert after and after == [fake.reset_stamps_ns[-1]] * len(after)


def test_after_a_failed_pick_and_place_the_memory_is_read_from_after_the_arm_parked(
        tmp_path) -> None:
    """A missed grasp or a slipped block may have moved blocks: the retry's block, and the next
    experiment's setting after a drop, come from a memory/blocks of an image stamped after the
    arm parked, with a settled frame, not from whichever the memory had."""
    codes = PickAndPlace.Result
    node, fake, _ = run_graph(tmp_path, max_experiments=2, reset_ahead_s=0.3,
                              failures=[codes.GRASP_MISSED, codes.BLOCK_SLIPPED])
    assert len(fake.goal_ns) >= 3 and fake.observations >= 2
    for failed in (0, 1):  # the retry after the miss; the next experiment's goal after the slip
        parked, next_goal = fake.result_ns[failed], fake.goal_ns[failed + 1]
        assert any(parked <= stamp <= next_goal and settled > 0
                   for stamp, settled in fake.frames), (failed, parked, next_goal)


def test_unreachable_picks_try_another_block_and_unreachable_places_drop(tmp_path) -> None:
    codes = PickAndPlace.Result
    node, fake, _ = run_graph(tmp_path, max_experiments=2, failures=[
        codes.PICK_UNREACHABLE, codes.PLACE_UNREACHABLE, codes.BLOCK_SLIPPED])
    records = read_log(tmp_path)
    assert [g.block_id for g in fake.goals[:2]] == ["b1", "b2"], "another block after b1"
    assert records[0]["dropped_before"] == {"block_slipped": 1, "place_unreachable": 1}
    assert records[0]["attempts"] == 1 and records[0]["moved_block"] != "b1"


def test_the_policy_result_names_are_the_interface_constants() -> None:
    for name in POLICY_RESULTS:
        assert _code_name(getattr(PickAndPlace.Result, name.upper())) == name


def test_the_first_experiment_waits_until_the_arm_reports_ready(tmp_path) -> None:
    with Graph(tmp_path, max_experiments=2, fake_kwargs={"arm_ready": False}) as g:
        # everything else is up: the node waits for the driver alone (and says so)
        g.wait(lambda: g.fake.observations == 0 and g.node.environment._missing() == [
            "arm_ready (the driver connected and calibrated)"], what="only arm_ready missing")
        assert not g.fake.goals and not g.node.finished.is_set()
        g.fake.ready_pub.publish(Bool(data=True))
        g.wait(g.node.finished.is_set, what="the run after the arm became ready")
        assert len(read_log(tmp_path)) == 2


def test_a_graph_that_never_becomes_ready_ends_the_wait_with_a_reason(tmp_path) -> None:
    with Graph(tmp_path, max_experiments=2, ready_timeout_s=0.5,
               fake_kwargs={"arm_ready": False}) as g:
        g.wait(g.node.finished.is_set, what="the bounded wait ending")
        assert not g.fake.goals and not (tmp_path / "experience.jsonl").exists()


def test_the_backend_reset_service_is_found_or_named(tmp_path) -> None:
    with Graph(tmp_path / "a", max_experiments=1) as g:
        g.wait(g.node.finished.is_set)
        assert g.node.environment.reset_client.srv_name == "/sim_node/reset_world"
    driver_reset = [(ResetWorld, "katana_driver_node/reset_world")]
    with Graph(tmp_path / "b", max_experiments=1, ready_timeout_s=0.5,
               probe_services=driver_reset) as g:
        g.wait(g.node.finished.is_set)
        assert not (tmp_path / "b" / "experience.jsonl").exists(), "two resets: not ready"
        assert any("not 2" in m for m in g.node.environment._missing())
    with Graph(tmp_path / "c", max_experiments=1, reset_service="katana_driver_node/reset_world",
               probe_services=driver_reset) as g:
        g.wait(g.node.finished.is_set)
        assert len(read_log(tmp_path / "c")) == 1
        assert g.node.environment.reset_client.srv_name == "katana_driver_node/reset_world"


def test_save_answers_failure_when_the_run_folder_is_gone(tmp_path) -> None:
    run_dir = tmp_path / "run"
    with Graph(run_dir, max_experiments=1) as g:
        g.wait(g.node.finished.is_set)
        client = g.probe.create_client(Trigger, "curiosity_node/save")
        assert client.wait_for_service(timeout_sec=10.0)
        ok = g.result(client.call_async(Trigger.Request()))
        assert ok.success and "1 experiments" in ok.message
        for f in run_dir.iterdir():
            f.unlink()
        run_dir.rmdir()
        failed = g.result(client.call_async(Trigger.Request()))
        assert not failed.success and str(run_dir) in failed.message
        again = g.result(client.call_async(Trigger.Request()))  # the node is still serving
        assert not again.success


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (Linux)")
def test_save_on_a_full_disk_answers_failure_and_keeps_the_last_checkpoint(tmp_path) -> None:
    """The checkpoint's temporary file is routed to /dev/full, whose writes fail with ENOSPC as
    on a full disk: ~/save answers why, the previous checkpoint and the log are untouched, and
    the node keeps serving."""
    with Graph(tmp_path, max_experiments=1) as g:
        g.wait(g.node.finished.is_set)
        client = g.probe.create_client(Trigger, "curiosity_node/save")
        assert client.wait_for_service(timeout_sec=10.0)
        assert g.result(client.call_async(Trigger.Request())).success
        checkpoint = tmp_path / CHECKPOINT_NAME
        before = checkpoint.read_bytes()
        log_before = (tmp_path / "experience.jsonl").read_bytes()
        (tmp_path / "learner.tmp.npz").symlink_to("/dev/full")
        failed = g.result(client.call_async(Trigger.Request()))
        assert not failed.success and "No space left on device" in failed.message
        assert checkpoint.read_bytes() == before and load_checkpoint(checkpoint)[1] == 1
        assert (tmp_path / "experience.jsonl").read_bytes() == log_before
        (tmp_path / "learner.tmp.npz").unlink()  # space again: the next save works
        assert g.result(client.call_async(Trigger.Request())).success


def test_stop_ends_the_node_mid_experiment_with_the_log_intact(tmp_path) -> None:
    hold = threading.Event()
    hold.set()
    with Graph(tmp_path, max_experiments=50, fake_kwargs={"hold_goals": hold}) as g:
        g.wait(g.fake.goal_started.is_set, what="a pick-and-place in progress")
        g.node.stop()  # what run_node calls on SIGINT / SIGTERM
        assert not g.node._thread.is_alive(), "stop() ended the experiment thread"
        assert g.node.finished.is_set()
    hold.clear()  # after the graph closed: the held goal's late result goes nowhere
    assert not (tmp_path / "experience.jsonl").exists() or read_log(tmp_path) == []


# -- a signal ends the node process mid-experiment, cleanly ---------------------------------


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_ends_the_node_process_mid_experiment(tmp_path, sig) -> None:
    domain = private_domain_id()  # this test process alone
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    saved = {k: os.environ.get(k) for k in ("ROS_AUTOMATIC_DISCOVERY_RANGE",)}
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # read when the context starts
    context = rclpy.context.Context()
    try:
        rclpy.init(context=context, domain_id=domain)
    finally:
        for k, v in saved.items():
            os.environ.pop(k, None) if v is None else os.environ.__setitem__(k, v)
    hold = threading.Event()
    hold.set()
    executor = MultiThreadedExecutor(num_threads=4, context=context)
    fake = FakeGraph(context, hold_goals=hold)
    executor.add_node(fake)
    spin = threading.Thread(target=executor.spin, daemon=True)
    spin.start()
    proc = subprocess.Popen(
        [sys.executable, "-m", "katana_curiosity.curiosity_node", "--ros-args",
         "-p", f"run_dir:={tmp_path}", "-p", "max_experiments:=50", "-p", "ready_timeout_s:=60.0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert fake.goal_started.wait(60.0), "no experiment started"
        start = time.monotonic()
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=10.0)  # a hang guard; the figure is printed
        print(f"{signal.Signals(sig).name}: curiosity_node ended in "
              f"{time.monotonic() - start:.2f} s")
    finally:
        proc.kill() if proc.poll() is None else None
        hold.clear()
        executor.shutdown()
        fake.destroy_node()
        rclpy.shutdown(context=context)
        spin.join(timeout=5)
    assert proc.returncode == 0, err
    assert "Traceback" not in err and "Traceback" not in out, err
    assert not (tmp_path / "experience.jsonl").exists() or read_log(tmp_path) == []
