"""curiosity_node's inputs: its parameters at start-up and live, the run folder's log at
start-up, the pick reach, and arbitrary messages on its topics (answered, never crashed on)."""

import json
import math
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import rclpy
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from katana_common.params import ParameterError
from katana_common.qos import STATE_QOS
from katana_curiosity.core.block_choice import PickReach
from katana_curiosity.curiosity_node import CuriosityNode
from katana_curiosity.robot_environment import BLOCKS_TOPIC
from katana_interfaces.msg import Block, BlockArray, FoveaInstance
from katana_manipulation.core.pick_place import PickPlaceParams
from katana_manipulation.pick_place_executor import PickPlaceExecutor
from katana_manipulation.testing import pick_limit_m
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib
from curiosity_graph import Graph, params, run_graph  # noqa: E402


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
