"""The graph around curiosity_node for its in-process tests (test_curiosity_node.py,
test_curiosity_node_inputs.py): fakes of fovea_node, perception_node, block_memory_node, the
executor and the sim (FakeGraph), the node and the fakes on one executor (Graph), and the run
folder's experience log (read_log). Not a test module: the tests import it from this folder."""

import json
import threading
import time
import uuid

import numpy as np
import rclpy
from katana_common.executor import BackgroundSpin, MultiThreadedExecutor
from katana_common.qos import STATE_QOS
from katana_common.testing import wait_until
from katana_curiosity.curiosity_node import CuriosityNode
from katana_curiosity.robot_environment import BLOCKS_TOPIC
from katana_interfaces.action import PickAndPlace
from katana_interfaces.msg import Block, BlockArray, Experience, FoveaInstance, LearnerState
from katana_interfaces.srv import FindPlacement, JudgePlacement, ObserveSetting, ResetWorld
from rclpy.action import ActionServer
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool

BLOCK_XY = [(0.2, 0.1), (0.2, -0.1), (0.25, 0.0), (0.18, 0.05)]


class FakeGraph(Node):
    """Stands in for fovea_node, perception_node, block_memory_node, executor and sim."""

    def __init__(self, context, *, unusable_first: int = 0, grasp_misses: int = 0,
                 hold_goals: threading.Event | None = None, arm_ready: bool | None = None,
                 failures: list[int] | None = None, reset_ahead_s: float | None = None) -> None:
        """reset_ahead_s: the reset answers that the new scene stands from this far ahead of
        the clock (ResetWorld's stamp), and the memory stamps its frames with the clock."""
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
        self.reset_ahead_s = reset_ahead_s
        self.reset_stamps_ns: list[int] = []
        self.frame_ns = 0  # the stamp of the last memory/blocks published
        self.frames: list[tuple[int, int]] = []  # (stamp, settled frames) of each one (stamped)
        self.goal_ns: list[int] = []  # the clock when each goal came
        self.result_ns: list[int] = []  # ... and when its result went out
        self.seen_at_observe: list[tuple[int, int]] = []  # (frame stamp, settled frames)
        self.experiences: list[Experience] = []
        self.echo = (-1, 0)  # (last experience, settled frames), as block_memory_node numbers them
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
        self.create_timer(0.02, self.publish_frame)

    def publish_frame(self) -> None:
        self.echo = (self.echo[0], self.echo[1] + 1)
        self.publish_blocks()

    def publish_blocks(self) -> None:
        self.joints_pub.publish(JointState(name=["j"], position=[0.0]))
        msg = BlockArray(experience=self.echo[0], settled_frames=self.echo[1])
        msg.header.frame_id = "world"
        if self.reset_ahead_s is not None:
            self.frame_ns = self.get_clock().now().nanoseconds
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(self.frame_ns, 10**9)
            self.frames.append((self.frame_ns, msg.settled_frames))
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
        self.seen_at_observe.append((self.frame_ns, self.echo[1]))
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
        self.goal_ns.append(self.get_clock().now().nanoseconds)
        self.goal_started.set()
        while self.hold_goals is not None and self.hold_goals.is_set():
            time.sleep(0.01)
        try:
            goal_handle.succeed()
        except Exception:  # noqa: BLE001 - the test graph closed under a held goal
            return PickAndPlace.Result()
        self.result_ns.append(self.get_clock().now().nanoseconds)
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
        if self.reset_ahead_s is not None:
            stood = self.get_clock().now().nanoseconds + int(self.reset_ahead_s * 1e9)
            self.reset_stamps_ns.append(stood)
            response.stamp.sec, response.stamp.nanosec = divmod(stood, 1_000_000_000)
            self.echo = (self.echo[0], 0)  # the new scene changed the levels
        return response

    def on_experience(self, msg: Experience) -> None:
        self.experiences.append(msg)
        self.echo = (int(msg.index), 0)
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

    def __init__(self, run_dir, max_experiments: int, fake_kwargs=None, probe_services=(),
                 **node_params) -> None:
        """probe_services: (type, name) pairs the probe serves before the node exists, so that
        the node's first look at the graph already finds them (created after it started, a
        service could be discovered only after the node had checked and begun)."""
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context)
        self.executor = MultiThreadedExecutor(num_threads=6, context=self.context)
        self.fake = FakeGraph(self.context, **(fake_kwargs or {}))
        self.probe = Node(f"probe_{uuid.uuid4().hex[:8]}", context=self.context)
        for srv_type, name in probe_services:
            self.probe.create_service(srv_type, name, lambda _q, r: r)
        self.node = CuriosityNode(context=self.context, parameter_overrides=params(
            run_dir, max_experiments=max_experiments, **node_params))
        self.states: list[LearnerState] = []
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
