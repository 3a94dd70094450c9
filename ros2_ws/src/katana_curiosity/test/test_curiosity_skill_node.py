"""skill_node without an arm: every build_stack goal is answered with a reason, the node keeps
serving, and a model it cannot load stops it at start-up naming the parameter."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import rclpy
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from katana_common.action_client import ActionClient
from katana_common.executor import MultiThreadedExecutor
from katana_common.params import ParameterError
from katana_curiosity.core.robot_loop import robot_bank
from katana_curiosity.core.run_record import CHECKPOINT_NAME, save_checkpoint
from katana_curiosity.core.skill import LearnedModel, SkillWorld, StackingSkill, build_stack
from katana_curiosity.node_params import PARAMS as CURIOSITY_PARAMS
from katana_curiosity.node_params import ROBOT_PARAMS
from katana_curiosity.skill_node import PARAMS as SKILL_PARAMS
from katana_curiosity.skill_node import SkillNode, load_model
from katana_interfaces.action import BuildStack
from katana_manipulation.core.pick_place import PickPlaceParams
from katana_manipulation.pick_place_executor import PickPlaceExecutor
from katana_manipulation.testing import place_limit_m
from rclpy.context import Context
from rclpy.parameter import Parameter


@pytest.fixture(scope="module")
def graph():
    ctx = Context()
    rclpy.init(context=ctx)
    node = SkillNode(context=ctx, parameter_overrides=[Parameter("ready_timeout_s", value=0.2)])
    client_node = rclpy.create_node("skill_goal_client", context=ctx)
    executor = MultiThreadedExecutor(num_threads=4, context=ctx)
    executor.add_node(node)
    executor.add_node(client_node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    client = ActionClient(client_node, BuildStack, "build_stack")
    assert client.wait_for_server(timeout_sec=10.0)
    yield client
    node.stop()
    executor.shutdown(timeout_sec=5.0)
    node.destroy_node()
    client_node.destroy_node()
    rclpy.try_shutdown(context=ctx)


def _send(client, goal):
    future = client.send_goal_async(goal)
    deadline = time.monotonic() + 20.0
    while not future.done():
        assert time.monotonic() < deadline, "no goal response"
        time.sleep(0.01)
    handle = future.result()
    result = handle.get_result_async()
    while not result.done():
        assert time.monotonic() < deadline, "no result"
        time.sleep(0.01)
    return result.result().result


@settings(max_examples=12, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.integers(0, 255), st.integers(0, 65535))
def test_every_goal_is_answered_with_a_reason(graph, target, bound):
    result = _send(graph, BuildStack.Goal(target_height=target, max_placements=bound))
    assert not result.success and result.reason
    if not 1 <= target <= 4:  # the untrained model covers heights 0..3: stacks of 1..4
        assert result.error_code == BuildStack.Result.INVALID_GOAL
        assert str(target) in result.reason
    else:  # no arm in this graph: it says what it waited for
        assert result.error_code == BuildStack.Result.EXECUTION_FAILED
        assert "not ready" in result.reason


def test_an_unloadable_model_stops_the_node_naming_the_parameter(tmp_path):
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        with pytest.raises(ParameterError, match="'model'"):
            SkillNode(context=ctx,
                      parameter_overrides=[Parameter("model", value=str(tmp_path / "none"))])
    finally:
        rclpy.try_shutdown(context=ctx)


def test_the_model_is_the_runs_learned_margins(tmp_path):
    bank = robot_bank(3, 6, 1.0, 0.1)
    for _ in range(5):
        bank.update(1, 5, 1.0)
        bank.update(2, 0, -1.0)
    save_checkpoint(tmp_path / CHECKPOINT_NAME, bank, 10)
    model = load_model(str(tmp_path), 3, 6)
    np.testing.assert_allclose(model.margin, bank.margin)
    assert model.margin[1, 5] > 0.5 and model.margin[2, 0] < -0.5
    np.testing.assert_array_equal(load_model("", 3, 6).margin, np.zeros((5, 6)))
    with pytest.raises(ValueError, match="7 x 6"):
        load_model(str(tmp_path), 6, 6)


def test_an_attempt_that_placed_nothing_is_chosen_anew_within_the_bound():
    """place() returning 0 (the arm lost the block) records no outcome, and counts towards
    the bound: the skill observes again."""
    class World(SkillWorld):
        def __init__(self, labels):
            self.labels, self.height, self.calls = list(labels), 1, 0

        def offered(self):
            return [(0, 1)] + [(h, 6) for h in range(1, self.height + 1)]

        def place(self, state, action):
            self.calls += 1
            label = self.labels.pop(0)
            if label > 0:
                self.height = state + 1
            return label

        def highest_stack(self):
            return self.height

    skill = StackingSkill(LearnedModel.from_margins(np.full((5, 6), 0.9)), target_height=3)
    world = World([0, 1, 0, 1])
    result = build_stack(world, skill, max_placements=6)
    assert result.reached and world.calls == 4
    assert [p.label for p in result.placements] == [1, 1]
    bounded = build_stack(World([0, 0, 0]), skill, max_placements=3)
    assert not bounded.reached and bounded.placements == []
    assert bounded.reason == "placement bound reached"


def test_the_skill_node_shares_the_curiosity_nodes_parameters_and_the_executors_reach():
    """One definition of the parameters both nodes declare (so one default each), the reset
    service reaches the skill's environment, and its placement reach follows the executor's
    geometry: the far edge on a stack of three lies where the executor's planner, with the
    same grasp_offset, stops finding a plan (from its kinematics, without core.reach)."""
    for spec in ROBOT_PARAMS:
        assert spec in SKILL_PARAMS and spec in CURIOSITY_PARAMS, spec.name
    shared = [Parameter("grasp_offset", value=-0.015)]  # a lower grip: a taller stack reachable
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        node = SkillNode(context=ctx, parameter_overrides=[
            Parameter("reset_service", value="katana_driver_node/reset_world"), *shared])
        executor = PickPlaceExecutor(context=ctx, parameter_overrides=shared)
        assert node.environment.config.reset_service == "katana_driver_node/reset_world"
        assert node.params["ready_timeout_s"] == node.params.spec("ready_timeout_s").default
        near, far = node.place_reach_m[3]
        limit = place_limit_m(executor.planner.p, 3, inside=0.5 * (near + far))
        assert limit - 0.01 <= far <= limit
        assert far > place_limit_m(PickPlaceParams(), 3, inside=0.15) + 0.02
        node.stop()
        node.destroy_node()
        executor.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)
