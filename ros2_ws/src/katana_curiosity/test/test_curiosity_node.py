"""curiosity_node in-process against fake fovea, judge, pick-and-place and memory servers."""

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

import numpy as np
import pytest
import rclpy
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from katana_common.executor import BackgroundSpin, MultiThreadedExecutor
from katana_common.params import ParameterError
from katana_common.qos import STATE_QOS
from katana_common.testing import private_domain_id, wait_until
from katana_curiosity.core.block_choice import PickReach
from katana_curiosity.core.robot_loop import robot_bank
from katana_curiosity.core.run_record import CHECKPOINT_NAME, load_checkpoint, replay
from katana_curiosity.curiosity_node import CuriosityNode
from katana_curiosity.robot_environment import BLOCKS_TOPIC
from katana_interfaces.action import PickAndPlace
from katana_interfaces.msg import Block, BlockArray, Experience, FoveaInstance, LearnerState
from katana_interfaces.srv import FindPlacement, JudgePlacement, ObserveSetting, ResetWorld
from rclpy.action import ActionServer
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

BLOCK_XY = [(0.2, 0.1), (0.2, -0.1), (0.25, 0.0), (0.18, 0.05)]


class FakeGraph(Node):
    """Stands in for fovea_node, perception_node, block_memory_node, executor and sim."""

    def __init__(self, context, *, unusable_first: int = 0, grasp_misses: int = 0,
                 hold_goals: threading.Event | None = None, arm_ready: bool | None = None,
                 failures: list[int] | None = None) -> None:
        super().__init__(f"fake_graph_{uuid.uuid4().hex[:8]}", context=context)
        self.rng = np.random.default_rng(0)
        self.unusable_first = unusable_first
        self.grasp_misses = grasp_misses
        self.failures = list(failures or [])  # result codes of the first goals
        self.hold_goals = hold_goals  # while set, goals wait (an experiment in progress)
        self.goal_started = threading.Event()
        self.observations = 0
        self.goals: list[PickAndPlace.Goal] = []
        self.resets = 0
        self.experiences: list[Experience] = []
        self.blocks_pub = self.create_publisher(BlockArray, BLOCKS_TOPIC, STATE_QOS)
        self.joints_pub = self.create_publisher(JointState, "joint_states", 10)
        self.create_service(ObserveSetting, "fovea/observe", self.observe)
        self.create_service(FindPlacement, "fovea/find_placement", self.find)
        self.create_service(JudgePlacement, "perception/judge_placement", self.judge)
        self.create_service(ResetWorld, "sim_node/reset_world", self.reset)
        self.create_subscription(Experience, "curiosity/experience", self.on_experience, 10)
        ActionServer(self, PickAndPlace, "pick_and_place", self.pick_place)
        if arm_ready is not None:  # like katana_driver_node (the sim has no arm_ready)
            self.ready_pub = self.create_publisher(Bool, "arm_ready", STATE_QOS)
            self.ready_pub.publish(Bool(data=arm_ready))
        self.publish_blocks()
        # like block_memory_node, which answers every camera frame with a memory/blocks
        self.create_timer(0.02, self.publish_blocks)

    def publish_blocks(self) -> None:
        self.joints_pub.publish(JointState(name=["j"], position=[0.0]))
        msg = BlockArray()
        msg.header.frame_id = "world"
        for i, (x, y) in enumerate(BLOCK_XY):
            b = Block(id=f"b{i}", color=f"c{i}", level=1, on_top=True, visible=True,
                      resting_pose_known=True)
            b.pose.position.x, b.pose.position.y, b.pose.position.z = x, y, 0.015
            msg.blocks.append(b)
        self.blocks_pub.publish(msg)

    def instance(self, state: int, action: int) -> FoveaInstance:
        inst = FoveaInstance(state=state, action=action)
        inst.features = [1.0 if k == action - 1 else 0.0 for k in range(6)] + [1.0]
        inst.placement.position.x, inst.placement.position.y = 0.2, 0.1
        inst.support_ids = ["b0"] if state else []
        return inst

    def observe(self, request, response):
        self.observations += 1
        response.success = True
        response.setting = self.observations
        if self.observations <= self.unusable_first:
            response.instances = [self.instance(9, 1), self.instance(1, 12)]  # nothing usable
            return response
        response.instances = [self.instance(s, a) for s in (0, 1) for a in range(1, 7)]
        return response

    def find(self, request, response):
        response.found = request.state in (0, 1)
        response.message = "" if response.found else "no stack of that height"
        if response.found:
            response.instance = self.instance(request.state, request.action)
        return response

    def judge(self, request, response):
        response.success = True
        if request.phase == JudgePlacement.Request.PHASE_AFTER:
            # actions with more overlap (higher index) are more stable
            p = 1.0 if request.instance.state == 0 else request.instance.action / 7
            response.label = 1 if self.rng.random() < p else -1
        return response

    def pick_place(self, goal_handle):
        self.goals.append(goal_handle.request)
        self.goal_started.set()
        while self.hold_goals is not None and self.hold_goals.is_set():
            time.sleep(0.01)
        try:
            goal_handle.succeed()
        except Exception:  # noqa: BLE001 - the test graph closed under a held goal
            return PickAndPlace.Result()
        if self.failures:
            return PickAndPlace.Result(success=False, error_code=self.failures.pop(0),
                                       message="scripted failure")
        if self.grasp_misses > 0:
            self.grasp_misses -= 1
            return PickAndPlace.Result(
                success=False, error_code=PickAndPlace.Result.GRASP_MISSED, message="grasp missed"
            )
        return PickAndPlace.Result(success=True, error_code=PickAndPlace.Result.SUCCESS)

    def reset(self, request, response):
        self.resets += 1
        response.success = True
        return response

    def on_experience(self, msg: Experience) -> None:
        self.experiences.append(msg)
        self.publish_blocks()  # the memory answers every experience with a fresh memory/blocks


def params(run_dir, **extra):
    values = {
        "run_dir": str(run_dir),
        "max_experiments": 8,
        "service_timeout_s": 2.0,
        "blocks_timeout_s": 2.0,
        "action_timeout_s": 5.0,
        "ready_timeout_s": 10.0,
        **extra,
    }
    return [Parameter(k, value=v) for k, v in values.items()]


class Graph:
    """The node and the fakes on one executor in an own context; closed on exit."""

    def __init__(self, run_dir, max_experiments: int, fake_kwargs=None, **node_params) -> None:
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context)
        self.executor = MultiThreadedExecutor(num_threads=6, context=self.context)
        self.fake = FakeGraph(self.context, **(fake_kwargs or {}))
        self.node = CuriosityNode(context=self.context, parameter_overrides=params(
            run_dir, max_experiments=max_experiments, **node_params))
        self.states: list[LearnerState] = []
        self.probe = Node(f"probe_{uuid.uuid4().hex[:8]}", context=self.context)
        self.probe.create_subscription(LearnerState, "curiosity/learner_state",
                                       self.states.append, STATE_QOS)
        for n in (self.fake, self.node, self.probe):
            self.executor.add_node(n)
        self.spin = BackgroundSpin(self.executor)

    def wait(self, condition, timeout_s: float = 30.0, what: str = "condition"):
        assert wait_until(condition, timeout_s, 0.01), f"{what} not met within {timeout_s} s"

    def result(self, future, timeout_s: float = 10.0):
        self.wait(future.done, timeout_s, "an answer")
        return future.result()

    def close(self) -> None:
        """The node's stop(), then the spinning ends, then teardown (as run_node does)."""
        self.node.stop()
        self.spin.stop()
        self.executor.shutdown(timeout_sec=5)
        for n in (self.fake, self.node, self.probe):
            self.executor.remove_node(n)
            n.destroy_node()
        rclpy.shutdown(context=self.context)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def run_graph(run_dir, max_experiments: int, timeout_s: float = 30.0, **fake_kwargs):
    with Graph(run_dir, max_experiments, fake_kwargs) as g:
        g.wait(g.node.finished.is_set, timeout_s, "the experiment loop finishing")
        g.wait(lambda: len(g.fake.experiences) >= g.node.loop.done_this_session, 5.0)
        return g.node, g.fake, g.states


def read_log(run_dir) -> list[dict]:
    return [json.loads(line) for line in (run_dir / "experience.jsonl").read_text().splitlines()]


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


def test_bad_instances_and_missed_grasps_do_not_stop_the_run(tmp_path) -> None:
    node, fake, _ = run_graph(tmp_path, max_experiments=4, unusable_first=2, grasp_misses=1)
    records = read_log(tmp_path)
    assert len(records) == 4
    assert records[0]["attempts"] == 2, "a missed grasp is retried"
    assert records[0]["dropped_before"] == {"no_usable_instance": 2}
    assert [r["setting"] for r in records] == [3, 4, 5, 6], "the paper's i: drops included"
    assert all(r["dropped_before"] == {} for r in records[1:])
    assert fake.observations >= 6


def test_unreachable_picks_try_another_block_and_unreachable_places_drop(tmp_path) -> None:
    codes = PickAndPlace.Result
    node, fake, _ = run_graph(tmp_path, max_experiments=2, failures=[
        codes.PICK_UNREACHABLE, codes.PLACE_UNREACHABLE, codes.BLOCK_SLIPPED])
    records = read_log(tmp_path)
    assert [g.block_id for g in fake.goals[:2]] == ["b1", "b2"], "another block after b1"
    assert records[0]["dropped_before"] == {"block_slipped": 1, "place_unreachable": 1}
    assert records[0]["attempts"] == 1 and records[0]["moved_block"] != "b1"


def test_the_policy_result_names_are_the_interface_constants() -> None:
    from katana_curiosity.core.robot_loop import POLICY_RESULTS
    from katana_curiosity.robot_environment import _code_name

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
    with Graph(tmp_path / "b", max_experiments=1, ready_timeout_s=0.5) as g:
        g.probe.create_service(ResetWorld, "katana_driver_node/reset_world", lambda q, r: r)
        g.wait(g.node.finished.is_set)
        assert not (tmp_path / "b" / "experience.jsonl").exists(), "two resets: not ready"
        assert any("not 2" in m for m in g.node.environment._missing())
    with Graph(tmp_path / "c", max_experiments=1,
               reset_service="katana_driver_node/reset_world") as g:
        g.probe.create_service(ResetWorld, "katana_driver_node/reset_world", lambda q, r: r)
        g.wait(g.node.finished.is_set)
        assert len(read_log(tmp_path / "c")) == 1
        assert g.node.environment.reset_client.srv_name == "katana_driver_node/reset_world"


def test_a_garbage_line_in_the_log_stops_the_start_and_changes_nothing(tmp_path) -> None:
    run_graph(tmp_path, max_experiments=4)
    path = tmp_path / "experience.jsonl"
    lines = path.read_bytes().splitlines(keepends=True)
    cases = {
        "(record)": lines[:2] + [b"garbage\n"] + lines[2:],
        "index": lines[:3] + [lines[2]],  # a duplicated line
    }
    # a non-finite number and an unknown state are refused too
    bad_label = json.loads(lines[1])
    bad_label["label"] = 0
    bad_state = json.loads(lines[2])
    bad_state["state"] = 9
    cases["label"] = lines[:1] + [json.dumps(bad_label).encode() + b"\n"] + lines[2:]
    cases["state"] = lines[:2] + [json.dumps(bad_state).encode() + b"\n"] + lines[3:]
    bad_margin = json.loads(lines[1])
    bad_margin["margin_before"] = math.nan
    cases["margin_before"] = lines[:1] + [json.dumps(bad_margin).encode() + b"\n"] + lines[2:]
    for field, content in cases.items():
        data = b"".join(content)
        path.write_bytes(data)
        context = rclpy.context.Context()
        rclpy.init(context=context)
        try:
            with pytest.raises(ParameterError) as err:
                CuriosityNode(context=context, parameter_overrides=params(tmp_path))
        finally:
            rclpy.shutdown(context=context)
        message = str(err.value)
        assert f"field '{field}'" in message and str(path) in message, message
        assert "\n" not in message
        assert path.read_bytes() == data, "nothing is rewritten"


def test_live_parameters_apply_and_bad_or_read_only_ones_are_refused(tmp_path) -> None:
    with Graph(tmp_path, max_experiments=2) as g:
        g.wait(g.node.finished.is_set, what="the run")
        client = AsyncParameterClient(g.probe, "curiosity_node")
        assert client.wait_for_services(timeout_sec=10.0)

        def set_one(name, value):
            n_states = len(g.states)
            answer = g.result(client.set_parameters([Parameter(name, value=value)]))
            return answer.results[0], n_states

        result, before = set_one("alpha", 2.5)
        assert result.successful, result.reason
        g.wait(lambda: len(g.states) > before, what="a learner_state after the change")
        assert g.states[-1].alpha == 2.5
        np.testing.assert_allclose(g.node.bank.rule.alpha, 2.5)

        result, before = set_one("strategy", "conf")
        assert result.successful, result.reason
        g.wait(lambda: len(g.states) > before)
        assert g.states[-1].strategy == "conf" and type(g.node.explorer.strategy).name == "conf"

        for name, value in [("alpha", -1.0), ("theta", 1.5), ("strategy", "bogus"),
                            ("gamma", 1.0)]:
            result, _ = set_one(name, value)
            assert not result.successful and name in result.reason
        assert g.node.bank.rule.alpha == 2.5 and g.node.strategy_name == "conf"
        got = g.result(client.get_parameters(["alpha", "strategy"]))
        assert [v.double_value for v in got.values[:1]] == [2.5]
        assert got.values[1].string_value == "conf"

        for name, value in [("max_height", 2), ("run_dir", "/tmp/x"), ("seed", 5)]:
            result, _ = set_one(name, value)
            assert not result.successful and "read-only" in result.reason
        assert g.node.max_height == 3


def test_a_live_change_mid_experiment_applies_before_the_next_learner_state(tmp_path) -> None:
    hold = threading.Event()
    hold.set()
    with Graph(tmp_path, max_experiments=3, fake_kwargs={"hold_goals": hold}) as g:
        g.wait(g.fake.goal_started.is_set, what="an experiment in progress")
        client = AsyncParameterClient(g.probe, "curiosity_node")
        assert client.wait_for_services(timeout_sec=10.0)
        answer = g.result(client.set_parameters([Parameter("theta", value=0.3)]))
        assert answer.results[0].successful
        assert g.node.bank.rule.theta == 0.1, "the learner does not change mid-experiment"
        hold.clear()
        # Found by experiment count, not by list position: the node's first learner_state
        # (transient local) may reach the probe late on a loaded machine.
        def first_after():
            return next((s for s in list(g.states) if s.experiments >= 1), None)

        g.wait(lambda: first_after() is not None, what="the learner_state after the experiment")
        after = first_after()
        assert after.experiments == 1 and after.theta == pytest.approx(0.3)
        assert all(s.theta == pytest.approx(0.1) for s in g.states if s.experiments == 0)
        g.wait(g.node.finished.is_set)


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


@pytest.mark.parametrize(
    ("name", "value", "match"),
    [
        ("strategy", "greedy", "strategy"),
        ("alpha", -1.0, "alpha"),
        ("theta", 1.5, "theta"),
        ("max_height", 12, "max_height"),
        ("run_dir", "", "run_dir"),
        ("table_action", 9, "table_action"),
        ("alhpa", 2.0, "alhpa"),
    ],
)
def test_invalid_parameters_stop_the_node_with_the_parameter_named(tmp_path, name, value, match):
    context = rclpy.context.Context()
    rclpy.init(context=context)
    try:
        overrides = params(tmp_path)
        overrides = [p for p in overrides if p.name != name] + [Parameter(name, value=value)]
        with pytest.raises(ParameterError, match=match):
            CuriosityNode(context=context, parameter_overrides=overrides)
    finally:
        rclpy.shutdown(context=context)


def test_the_pick_reach_is_the_executors_with_the_same_geometry(tmp_path) -> None:
    """grasp_offset given to every node (as graph.yaml's `/**` gives it) moves the curiosity
    node's pick reach with the executor's: each band's edges lie where the executor's planner,
    with that geometry, stops finding a plan (found from its kinematics, without core.reach),
    not where the default geometry's do."""
    from katana_manipulation.core.pick_place import PickPlaceParams
    from katana_manipulation.pick_place_executor import PickPlaceExecutor
    from katana_manipulation.testing import pick_limit_m

    shared = [Parameter("grasp_offset", value=-0.015)]  # a lower grip
    context = rclpy.context.Context()
    rclpy.init(context=context)
    try:
        node = CuriosityNode(context=context, parameter_overrides=params(tmp_path) + shared)
        executor = PickPlaceExecutor(context=context, parameter_overrides=shared)
        planned = executor.planner.p
        assert planned.grasp_offset == -0.015
        bands = node.environment.config.reach.bands_m
        for level, (near, far) in enumerate(bands[:3], start=1):
            mid = 0.5 * (near + far)
            nearest, farthest = (pick_limit_m(planned, level, mid, outside)
                                 for outside in (0.0, 0.6))
            assert nearest <= near <= nearest + 0.01 and farthest - 0.01 <= far <= farthest
        # the default grip reaches down to a block on one much nearer the pan axis
        assert bands[1][0] > pick_limit_m(PickPlaceParams(), 2, 0.15, outside=0.0) + 0.03
        node.destroy_node()
        executor.destroy_node()
    finally:
        rclpy.shutdown(context=context)


# -- arbitrary input on the subscribed topics never crashes or hangs the node --------------

_floats = st.floats(allow_nan=True, allow_infinity=True, width=32)
_block = st.builds(
    lambda i, x, y, z, level, on_top, known: (i, x, y, z, level, on_top, known),
    st.text(max_size=4), _floats, _floats, _floats, st.integers(0, 255), st.booleans(),
    st.booleans())


def _block_array(blocks) -> BlockArray:
    msg = BlockArray()
    for i, x, y, z, level, on_top, known in blocks:
        b = Block(id=i, level=level, on_top=on_top, resting_pose_known=known)
        b.pose.position.x, b.pose.position.y, b.pose.position.z = x, y, z
        msg.blocks.append(b)
    return msg


@pytest.fixture(scope="module")
def idle_node(tmp_path_factory):
    """A node whose loop has nothing to do (max_experiments reached), for direct calls."""
    run_dir = tmp_path_factory.mktemp("idle")
    with Graph(run_dir, max_experiments=1) as g:
        g.wait(g.node.finished.is_set)
        yield g


@settings(max_examples=150, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(blocks=st.lists(_block, max_size=6), state=st.integers(0, 255),
       action=st.integers(0, 255), px=_floats, py=_floats, supports=st.lists(st.text(max_size=3)))
def test_arbitrary_blocks_and_instances_are_answered_not_crashed(idle_node, blocks, state, action,
                                                                 px, py, supports) -> None:
    env = idle_node.node.environment
    msg = _block_array(blocks)
    env.on_blocks(msg)  # the subscription callback
    assert all(isinstance(b, str) for b in env.blocks_out_of_reach())
    inst = FoveaInstance(state=state, action=action, support_ids=supports)
    inst.placement.position.x, inst.placement.position.y = px, py
    chosen = env._choose_block(msg, inst, set())
    if chosen is not None:  # only a reachable top block outside the target stack, known upright
        assert chosen.on_top and chosen.id not in supports and chosen.resting_pose_known
        r = math.hypot(chosen.pose.position.x, chosen.pose.position.y)
        low, high = env.config.reach.bands_m[chosen.level - 1]
        assert low <= r <= high


def test_arbitrary_messages_on_the_topics_leave_the_node_serving(idle_node) -> None:
    g = idle_node
    blocks = g.probe.create_publisher(BlockArray, BLOCKS_TOPIC, STATE_QOS)
    joints = g.probe.create_publisher(JointState, "joint_states", 10)
    nasty = [(s, v, -v, v, 255, True, True) for s, v in
             [("", math.nan), ("\u00e9", math.inf), ("x" * 200, -1e30), ("b0", 0.0)]]
    for k in range(len(nasty)):
        blocks.publish(_block_array(nasty[: k + 1]))
        joints.publish(JointState(name=["a", "b"], position=[math.nan]))
    g.wait(lambda: g.node.environment.blocks_count() > 0)
    client = g.probe.create_client(Trigger, "curiosity_node/save")
    assert client.wait_for_service(timeout_sec=10.0)
    assert g.result(client.call_async(Trigger.Request())).success, "still serving"


@given(bands=st.lists(st.tuples(_floats, _floats), min_size=1, max_size=4),
       x=_floats, y=_floats, level=st.integers(-3, 300))
def test_pick_reach_answers_every_block(bands, x, y, level) -> None:
    try:
        reach = PickReach(tuple(bands))
    except ValueError:
        assert not all(math.isfinite(v) for b in bands for v in b)
        return
    ok = reach.can_pick(x, y, level)
    r = math.hypot(x, y)
    expected = 1 <= level <= len(bands) and bands[level - 1][0] <= r <= bands[level - 1][1]
    assert ok == expected


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
