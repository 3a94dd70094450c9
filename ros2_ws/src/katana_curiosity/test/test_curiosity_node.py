"""curiosity_node in-process against fake fovea, judge, pick-and-place and memory servers."""

import json
import threading
import time
import uuid

import numpy as np
import pytest
import rclpy
from katana_curiosity.core.predictors import PredictorBank, QueryRule, one_hot_with_bias
from katana_curiosity.core.run_record import replay
from katana_curiosity.curiosity_node import STATE_QOS, CuriosityNode
from katana_interfaces.action import PickAndPlace
from katana_interfaces.msg import Block, BlockArray, Experience, FoveaInstance, LearnerState
from katana_interfaces.srv import FindPlacement, JudgePlacement, ObserveSetting, ResetWorld
from rclpy.action import ActionServer
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter


class FakeGraph(Node):
    """Stands in for fovea_node, perception_node, block_memory_node, executor and sim."""

    def __init__(self, context, *, unusable_first: int = 0, grasp_misses: int = 0) -> None:
        super().__init__(f"fake_graph_{uuid.uuid4().hex[:8]}", context=context)
        self.rng = np.random.default_rng(0)
        self.unusable_first = unusable_first
        self.grasp_misses = grasp_misses
        self.observations = 0
        self.goals: list[PickAndPlace.Goal] = []
        self.resets = 0
        self.experiences: list[Experience] = []
        self.blocks_pub = self.create_publisher(BlockArray, "world/blocks", STATE_QOS)
        self.create_service(ObserveSetting, "fovea/observe", self.observe)
        self.create_service(FindPlacement, "fovea/find_placement", self.find)
        self.create_service(JudgePlacement, "perception/judge_placement", self.judge)
        self.create_service(ResetWorld, "sim_node/reset_world", self.reset)
        self.create_subscription(Experience, "curiosity/experience", self.on_experience, 10)
        ActionServer(self, PickAndPlace, "pick_and_place", self.pick_place)
        self.publish_blocks()
        # like block_memory_node, which answers every camera frame with a world/blocks
        self.create_timer(0.02, self.publish_blocks)

    def publish_blocks(self) -> None:
        msg = BlockArray()
        msg.header.frame_id = "world"
        for i, (x, y) in enumerate([(0.2, 0.1), (0.2, -0.1), (0.25, 0.0), (0.18, 0.05)]):
            b = Block(id=f"b{i}", color=f"c{i}", level=1, on_top=True, visible=True)
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
        goal_handle.succeed()
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
        self.publish_blocks()  # the memory answers every experience with a fresh world/blocks


def params(run_dir, **extra):
    values = {
        "run_dir": str(run_dir),
        "max_experiments": 8,
        "service_timeout_s": 2.0,
        "blocks_timeout_s": 2.0,
        "action_timeout_s": 5.0,
        **extra,
    }
    return [Parameter(k, value=v) for k, v in values.items()]


def run_graph(run_dir, max_experiments: int, timeout_s: float = 30.0, **fake_kwargs):
    context = rclpy.context.Context()
    rclpy.init(context=context)
    executor = MultiThreadedExecutor(num_threads=4, context=context)
    fake = FakeGraph(context, **fake_kwargs)
    node = CuriosityNode(
        context=context, parameter_overrides=params(run_dir, max_experiments=max_experiments)
    )
    states: list[LearnerState] = []
    listener = Node(f"listener_{uuid.uuid4().hex[:8]}", context=context)
    listener.create_subscription(LearnerState, "curiosity/learner_state", states.append, STATE_QOS)
    for n in (fake, node, listener):
        executor.add_node(n)
    spin = threading.Thread(target=executor.spin, daemon=True)
    spin.start()
    try:
        assert node.finished.wait(timeout_s), "the experiment loop did not finish in time"
        deadline = time.monotonic() + 5
        while len(fake.experiences) < node._done_this_session and time.monotonic() < deadline:
            time.sleep(0.01)
        return node, fake, states
    finally:
        node.stop()
        executor.shutdown()
        for n in (fake, node, listener):
            n.destroy_node()
        rclpy.shutdown(context=context)
        spin.join(timeout=5)


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
    bank = PredictorBank(range(4), one_hot_with_bias(6), QueryRule(1.0, 0.1), n_states=5)
    replay(bank, records)
    np.testing.assert_allclose(bank.w, node.bank.w)
    # each record's weights are the predictor before and after its own update
    for r in records:
        assert len(r["weights_before"]) == 7 and len(r["weights_after"]) == 7
        assert r["mode"] in ("query", "plan") and r["label"] in (-1, 1)
    assert (tmp_path / "learner.npz").exists()
    assert states and states[-1].experiments == 8
    assert [h.height for h in states[-1].heights] == [0, 1, 2, 3]


def test_a_restart_resumes_without_losing_or_repeating_an_experiment(tmp_path) -> None:
    run_graph(tmp_path, max_experiments=5)
    first = read_log(tmp_path)
    # a crash mid-write leaves a partial line: it was never recorded, so it is dropped
    with open(tmp_path / "experience.jsonl", "a") as f:
        f.write('{"index": 5, "state": 1, "act')
    node, fake, _ = run_graph(tmp_path, max_experiments=9)
    records = read_log(tmp_path)
    assert [r["index"] for r in records] == list(range(9))
    assert records[:5] == first
    assert int(node.bank.examples.sum()) == 9
    assert len(fake.experiences) == 4, "only the new experiments are run"


def test_bad_instances_and_missed_grasps_do_not_stop_the_run(tmp_path) -> None:
    node, fake, _ = run_graph(tmp_path, max_experiments=4, unusable_first=2, grasp_misses=1)
    records = read_log(tmp_path)
    assert len(records) == 4
    assert records[0]["attempts"] == 2, "a missed grasp is retried"
    assert fake.observations >= 6


@pytest.mark.parametrize(
    ("name", "value", "match"),
    [
        ("strategy", "greedy", "strategy"),
        ("alpha", -1.0, "alpha"),
        ("theta", 1.5, "theta"),
        ("max_height", 12, "max_height"),
        ("run_dir", "", "run_dir"),
    ],
)
def test_invalid_parameters_stop_the_node_with_the_parameter_named(tmp_path, name, value, match):
    context = rclpy.context.Context()
    rclpy.init(context=context)
    try:
        overrides = params(tmp_path)
        overrides = [p for p in overrides if p.name != name] + [Parameter(name, value=value)]
        with pytest.raises(Exception, match=match):
            CuriosityNode(context=context, parameter_overrides=overrides)
    finally:
        rclpy.shutdown(context=context)
