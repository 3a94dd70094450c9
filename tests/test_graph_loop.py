"""The paper's whole loop on the simulated arm, every node in one process (perception,
memory, fovea and curiosity): experiments are learned and logged once each, a restart resumes,
and bad input is refused while the run goes on."""

from __future__ import annotations

import json
import threading
import time

import numpy as np
from katana_bringup.in_process import InProcessGraph
from katana_bringup.run import build_nodes, default_params_files, load_params
from katana_common.action_client import ActionClient
from katana_common.qos import SENSOR_QOS, STATE_QOS
from katana_curiosity.curiosity_node import CuriosityNode
from katana_interfaces.action import PickAndPlace
from katana_interfaces.msg import Experience, LearnerState
from katana_interfaces.srv import FindPlacement
from katana_manipulation.pick_place_executor import PickPlaceExecutor
from katana_manipulation.ros_arm_port import RosArmPort
from katana_perception.perception_node import PerceptionNode
from sensor_msgs.msg import Image


def loop_params(run_dir, experiments: int, seed: int = 1) -> dict:
    params = load_params(default_params_files("sim"))
    params["sim_node"].update(real_time_factor=0.0, seed=seed, camera_rate=5.0)
    params["perception_node"]["publish_debug_image"] = False
    params["curiosity_node"].update(run_dir=str(run_dir), max_experiments=experiments, seed=seed)
    return params


def run_loop(graph, run_dir, experiments: int, check_before_start=None, seed: int = 1):
    nodes = build_nodes("sim", loop_params(run_dir, experiments, seed), graph.context)
    learner = next(n for n in nodes if n.get_name() == "curiosity_node")
    if check_before_start is not None:
        check_before_start(learner)  # nothing has spun yet: the learner is as constructed
    graph.add(*nodes)
    probe = graph.node("loop_test_probe")
    seen: list[Experience] = []
    states: list[LearnerState] = []
    probe.create_subscription(Experience, "curiosity/experience", seen.append, 10)
    probe.create_subscription(LearnerState, "curiosity/learner_state", states.append, STATE_QOS)
    return learner, probe, seen, states


def log_records(run_dir) -> list[dict]:
    return [json.loads(line) for line in (run_dir / "experience.jsonl").read_text().splitlines()]


def test_experiments_are_learned_logged_once_and_a_restart_resumes(tmp_path):
    with InProcessGraph() as g:
        learner, _, seen, states = run_loop(g, tmp_path, experiments=3)
        g.wait_for(learner.finished.is_set, timeout=150.0)
        g.wait_for(lambda: len(seen) == 3 and states and states[-1].experiments == 3)
        records = log_records(tmp_path)
        assert [r["index"] for r in records] == [0, 1, 2]
        assert int(learner.bank.examples.sum()) == 3, "one update per experiment"
        assert [m.index for m in seen] == [0, 1, 2]
        for r, m in zip(records, seen, strict=True):
            assert (m.instance.state, m.instance.action, m.label) == (
                r["state"], r["action"], r["label"])
            assert r["label"] in (-1, 1) and r["moved_block"] not in r["instance"]["support_ids"]
        weights = learner.bank.w.copy()

    with InProcessGraph() as g:  # a new process would do the same: the log is the record
        def rebuilt_from_the_log(learner) -> None:
            assert learner.experiments == 3
            np.testing.assert_allclose(learner.bank.w, weights)

        learner, _, seen, _ = run_loop(g, tmp_path, experiments=5,
                                       check_before_start=rebuilt_from_the_log)
        g.wait_for(learner.finished.is_set, timeout=150.0)
        g.wait_for(lambda: len(seen) == 2)
        again = log_records(tmp_path)
        assert [r["index"] for r in again] == [0, 1, 2, 3, 4]
        assert again[:3] == records, "nothing recorded is lost or rewritten"
        assert int(learner.bank.examples.sum()) == 5
        assert [m.index for m in seen] == [3, 4], "no experiment is run or counted twice"


def test_bad_input_is_refused_and_the_run_goes_on(tmp_path):
    with InProcessGraph() as g:
        learner, probe, seen, _ = run_loop(g, tmp_path, experiments=3)
        g.wait_for(lambda: len(seen) >= 1, timeout=120.0)

        # a malformed image: data far shorter than height x step
        bad = Image(height=480, width=640, encoding="rgb8", step=1920, data=b"\x00" * 100)
        pub = probe.create_publisher(Image, "camera/image_raw", SENSOR_QOS)
        for _ in range(3):
            pub.publish(bad)

        # a height that does not exist
        client = probe.create_client(FindPlacement, "fovea/find_placement")
        assert client.wait_for_service(timeout_sec=10.0)
        answer = g.result(client.call_async(FindPlacement.Request(state=9, action=3)))
        assert not answer.found and answer.message

        # an unreachable placement: refused before anything moves
        action = ActionClient(probe, PickAndPlace, "pick_and_place")
        assert action.wait_for_server(timeout_sec=10.0)
        goal = PickAndPlace.Goal(block_id="red")
        goal.pick.position.x, goal.pick.position.z = 0.2, 0.015
        goal.block_size.x = goal.block_size.y = 0.04
        goal.block_size.z = 0.03
        goal.place.position.x, goal.place.position.z = 0.65, 0.015
        goal.pick.orientation.w = goal.place.orientation.w = 1.0
        handle = g.result(action.send_goal_async(goal))
        if handle.accepted:
            result = g.result(handle.get_result_async(), timeout=60.0).result
            assert not result.success
            assert result.error_code in (PickAndPlace.Result.PLACE_UNREACHABLE,
                                         PickAndPlace.Result.INVALID_GOAL)
            assert result.message

        g.wait_for(learner.finished.is_set, timeout=150.0)
        assert len(log_records(tmp_path)) == 3, "the run finished despite the bad input"


#: what a run decides and observes; the times (wall_time, stage_s) vary from run to run
TIMES = ("wall_time", "stage_s")


def _first_difference(a: list[dict], b: list[dict]) -> str:
    for i, (ra, rb) in enumerate(zip(a, b, strict=False)):
        for key in sorted(set(ra) | set(rb)):
            if ra.get(key) != rb.get(key):
                return f"record {i}, field {key!r}: {ra.get(key)!r} vs {rb.get(key)!r}"
    return f"{len(a)} vs {len(b)} records"


def _late(cls: type, name: str, seconds: float, monkeypatch) -> None:
    """Make `cls.name` start `seconds` late: another thread timing, the same inputs."""
    original = getattr(cls, name)

    def late(self, *args, **kwargs):
        time.sleep(seconds)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(cls, name, late)


def _delivered_late(cls: type, name: str, seconds: float, monkeypatch) -> list[threading.Timer]:
    """Every call of `cls.name` (a subscription's callback) made `seconds` later on a timer of
    its own, in order, while the executor goes on: the messages reach the node late, as under
    load. Returns the timers, to be joined before the graph closes."""
    original = getattr(cls, name)
    timers: list[threading.Timer] = []

    def late(self, *args):
        timer = threading.Timer(seconds, original, (self, *args))
        timers.append(timer)
        timer.start()

    monkeypatch.setattr(cls, name, late)
    return timers


def _published_late(seconds: float, monkeypatch) -> list[threading.Timer]:
    """The curiosity node's experience goes out `seconds` after the loop moved on: the memory
    goes on folding images in meanwhile, as a slow link or a loaded machine would have it.
    Returns the timers, to be joined before the graph closes (the last one fires after the
    loop has ended)."""
    original = CuriosityNode._publish_experiment
    timers: list[threading.Timer] = []

    def late(self, record, step):
        timer = threading.Timer(seconds, original, (self, record, step))
        timers.append(timer)
        timer.start()

    monkeypatch.setattr(CuriosityNode, "_publish_experiment", late)
    return timers


def _two_runs(tmp_path, experiments: int, seed: int, make_late) -> list[list[dict]]:
    """The logs (wall times left out) of two runs of one seed; ``make_late()`` slows the
    second and returns the timers that deliver late, joined before its graph closes."""
    logs = []
    late: list[threading.Timer] = []
    for run in ("first", "second"):
        if run == "second":
            late = make_late()
        with InProcessGraph() as g:
            learner, _, _, _ = run_loop(g, tmp_path / run, experiments=experiments, seed=seed)
            g.wait_for(learner.finished.is_set, timeout=250.0)
            for timer in list(late):  # delivered into a live graph, not a closed one
                timer.join()
        logs.append([{k: v for k, v in r.items() if k not in TIMES}
                     for r in log_records(tmp_path / run)])
    assert len(logs[0]) == experiments
    return logs


def test_two_fast_sim_runs_with_one_seed_write_the_same_log(tmp_path, monkeypatch):
    """Deterministic under a seed: settings, choices, instances, blocks moved, labels and
    dropped attempts are the same in two runs (the sim steps in lock-step with the motions,
    the loop makes no choice by the clock). In the second run every experience reaches the
    memory late while images keep coming, and the perception hears the memory late, so that
    frames are segmented on the levels from before the experience: only the ordering (the
    memory's experience numbering, not a time margin) keeps the runs together."""

    def make_late() -> list[threading.Timer]:
        _late(PerceptionNode, "on_memory_blocks", 0.12, monkeypatch)
        _late(RosArmPort, "_send", 0.05, monkeypatch)
        return _published_late(0.4, monkeypatch)

    logs = _two_runs(tmp_path, 5, 3, make_late)
    assert logs[0] == logs[1], _first_difference(*logs)


def test_joint_states_heard_late_do_not_part_two_runs(tmp_path, monkeypatch):
    """The executor hears joint_states 0.3 s late in the second run, longer than the loop's
    work between two tasks: a task would start from the arm as it was before the last one
    ended. It waits for the arm shown where its last task left it (RosArmPort.settled), so the
    runs write the same log."""
    logs = _two_runs(tmp_path, 8, 2, lambda: _delivered_late(
        PickPlaceExecutor, "_on_joints", 0.3, monkeypatch))
    assert logs[0] == logs[1], _first_difference(*logs)


def test_a_perception_busy_with_the_memory_judges_as_a_prompt_one(tmp_path, monkeypatch):
    """In the second run the perception takes each memory/blocks 0.3 s late, holding its
    input callbacks meanwhile. The judge's "before" is the memory the learner acted on and an
    image at least as new as the one it was built from (JudgePlacement.blocks_sequence), and
    an experience reaches the memory only once it has settled on the scene after the task
    (RobotEnvironment.wait_for_scene_after): the runs write the same log. Without the two, the
    judge took whatever memory and image the perception held, and two runs of this seed
    labelled an experiment differently in two of four tries."""

    def make_late() -> list[threading.Timer]:
        _late(PerceptionNode, "on_memory_blocks", 0.3, monkeypatch)
        return []

    logs = _two_runs(tmp_path, 3, 6, make_late)
    assert logs[0] == logs[1], _first_difference(*logs)
