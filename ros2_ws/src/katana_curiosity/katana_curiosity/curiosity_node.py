"""curiosity_node: the paper's exploration loop on the (simulated or real) arm.

Drives the core explorer unchanged, through RosWorld. After every experiment it appends the
experience to experience.jsonl (flushed and fsynced), checkpoints the learner, and publishes
curiosity/experience, curiosity/learner_state and curiosity/markers. Started on a run folder
that already has a log, it replays the log and carries on: nothing recorded is lost and no
experiment is counted twice.
"""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path

import numpy as np
import rclpy
from builtin_interfaces.msg import Duration
from geometry_msgs.msg import Point
from katana_interfaces.msg import BlockArray, Experience, HeightModel, LearnerState
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import ColorRGBA
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker, MarkerArray

from .core.explorer import MODE_NAMES, STRATEGIES, Explorer, make_strategy
from .core.predictors import PredictorBank, QueryRule, one_hot_with_bias
from .core.run_record import (
    CHECKPOINT_NAME,
    LOG_NAME,
    ExperienceLog,
    load_checkpoint,
    replay,
    save_checkpoint,
)
from .core.world import PlacementUnavailable
from .ros_world import ExperimentAborted, RosWorld, Timeouts

STATE_QOS = QoSProfile(
    depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE
)


def _float(description: str, low: float, high: float) -> ParameterDescriptor:
    return ParameterDescriptor(
        description=description,
        floating_point_range=[FloatingPointRange(from_value=low, to_value=high, step=0.0)],
    )


def _int(description: str, low: int, high: int) -> ParameterDescriptor:
    return ParameterDescriptor(
        description=description, integer_range=[IntegerRange(from_value=low, to_value=high, step=1)]
    )


class CuriosityNode(Node):
    """Curiosity learner and planner (paper sections 2.3-2.6) as a ROS 2 node."""

    def __init__(self, **kwargs) -> None:
        super().__init__("curiosity_node", **kwargs)
        p = self.declare_parameter
        p(
            "strategy",
            "q1",
            ParameterDescriptor(
                description=f"exploration strategy: one of {', '.join(STRATEGIES)}"
            ),
        )
        p("alpha", 1.0, _float("query condition scale alpha (Eq. 2)", 1e-3, 100.0))
        p(
            "theta",
            0.1,
            _float("query condition threshold theta (Eq. 2); 0.1 on the robot", 0.0, 1.0),
        )
        p("gamma", 0.95, _float("discount factor of the planner", 0.0, 0.999))
        p("max_height", 3, _int("highest stack height placed upon (heights 0..max_height)", 0, 7))
        p("n_actions", 6, _int("actions per state: bits on + 1 (six on the robot)", 1, 32))
        p("table_action", 1, _int("the only action a placement on the table (height 0) can "
                                  "have (no block in the fovea: bits off); 0 = any", 0, 32))
        p(
            "run_dir",
            "runs/robot",
            ParameterDescriptor(
                description="folder for experience.jsonl and learner.npz; resumes if they exist"
            ),
        )
        p(
            "max_experiments",
            0,
            _int("stop after this many experiments in total (0: never)", 0, 10_000_000),
        )
        p("seed", 0, _int("seed of the strategy's random choices", 0, 2**31 - 1))
        p(
            "grasp_retries",
            2,
            _int("retries of a missed grasp before the experiment is dropped", 0, 10),
        )
        p("service_timeout_s", 10.0, _float("timeout of each service call, s", 0.1, 600.0))
        p("action_timeout_s", 120.0, _float("timeout of one pick-and-place, s", 1.0, 3600.0))
        p("blocks_timeout_s", 10.0, _float("wait for a fresh world/blocks, s", 0.1, 600.0))
        p("reach_min_m", 0.14, _float("blocks nearer the pan axis are out of reach, m", 0.0, 1.0))
        p(
            "reach_max_m",
            0.29,
            _float("blocks further from the pan axis are out of reach, m", 0.0, 2.0),
        )
        p(
            "reach_max_by_level",
            [0.285, 0.28, 0.25, 0.20],
            ParameterDescriptor(
                description="farthest block the arm can pick from above, per block level 1, 2, "
                "... (last entry holds above), m; taller stacks are reachable less far"
            ),
        )
        p(
            "reset_service",
            "sim_node/reset_world",
            ParameterDescriptor(
                description="ResetWorld service called when blocks leave the reachable area"
            ),
        )
        p("stuck_reset", 3, _int("ask for a reset after this many experiments in a row whose "
                                 "setting offered only the table (0: never)", 0, 1000))
        p("frame_id", "world", ParameterDescriptor(description="frame of the markers"))

        g = self.get_parameter
        self.strategy_name = g("strategy").value
        if self.strategy_name not in STRATEGIES:
            raise ValueError(
                f"parameter 'strategy' is {self.strategy_name!r}; valid: {', '.join(STRATEGIES)}"
            )
        if not g("run_dir").value:
            raise ValueError("parameter 'run_dir' must be a non-empty folder path")
        if g("reach_min_m").value >= g("reach_max_m").value:
            raise ValueError("parameters 'reach_min_m' and 'reach_max_m': need min < max")
        reach_by_level = tuple(float(r) for r in g("reach_max_by_level").value)
        if not all(g("reach_min_m").value < r <= 2.0 for r in reach_by_level):
            raise ValueError("parameter 'reach_max_by_level': every entry must be in "
                             "(reach_min_m, 2.0] m")
        self.max_height = g("max_height").value
        self.n_actions = g("n_actions").value
        self.max_experiments = g("max_experiments").value
        self.frame_id = g("frame_id").value
        self.run_dir = Path(g("run_dir").value)

        # -- learner, restored from the run folder -------------------------------------------
        self.rule = QueryRule(g("alpha").value, g("theta").value)
        self.bank = PredictorBank(
            range(self.max_height + 1),
            one_hot_with_bias(self.n_actions),
            self.rule,
            n_states=self.max_height + 2,
        )
        self.log = ExperienceLog(self.run_dir / LOG_NAME)
        if self.log.dropped_partial_line:
            self.get_logger().warning("dropped a partially written last line of the log")
        replayed = replay(self.bank, self.log.records)
        self._check_checkpoint(replayed)
        feasible = np.ones((self.max_height + 2, self.n_actions), dtype=bool)
        table_action = g("table_action").value
        if table_action > self.n_actions:
            raise ValueError(
                f"parameter 'table_action' is {table_action}; valid: 0..{self.n_actions}"
            )
        if table_action:
            feasible[0] = False
            feasible[0, table_action - 1] = True
        strategy = make_strategy(
            self.strategy_name,
            self.bank,
            self.max_height + 1,
            g("gamma").value,
            seed=g("seed").value + replayed,
            feasible=feasible,
        )
        self.strategy = strategy

        # -- graph ---------------------------------------------------------------------------
        self._io_group = ReentrantCallbackGroup()
        self.world = RosWorld(
            self,
            n_actions=self.n_actions,
            max_height=self.max_height,
            grasp_retries=g("grasp_retries").value,
            timeouts=Timeouts(
                g("service_timeout_s").value,
                g("action_timeout_s").value,
                g("blocks_timeout_s").value,
            ),
            reach=(g("reach_min_m").value, g("reach_max_m").value),
            reach_by_level=reach_by_level,
            callback_group=self._io_group,
        )
        self.explorer = Explorer(self.world, self.bank, strategy, record_weights=True)
        self.explorer.steps = replayed
        self.create_subscription(
            BlockArray,
            "world/blocks",
            self.world.on_blocks,
            STATE_QOS,
            callback_group=self._io_group,
        )
        self.experience_pub = self.create_publisher(Experience, "curiosity/experience", 10)
        self.state_pub = self.create_publisher(LearnerState, "curiosity/learner_state", STATE_QOS)
        self.marker_pub = self.create_publisher(MarkerArray, "curiosity/markers", 10)
        self.create_service(
            Trigger, "~/save", self._on_save, callback_group=MutuallyExclusiveCallbackGroup()
        )
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.finished = threading.Event()
        self._thread: threading.Thread | None = None
        self._started_at = time.monotonic()
        self._done_this_session = 0
        self._dropped = 0
        self._table_only = 0
        self.publish_state()
        self.get_logger().info(
            f"strategy {self.strategy_name}, heights 0..{self.max_height}, {self.n_actions} "
            f"actions, alpha {self.rule.alpha}, theta {self.rule.theta}; run folder "
            f"{self.run_dir} ({replayed} experiments replayed)"
        )
        self._start_timer = self.create_timer(0.0, self._start_once)

    # -- lifecycle -----------------------------------------------------------------------

    def _check_checkpoint(self, replayed: int) -> None:
        path = self.run_dir / CHECKPOINT_NAME
        if not path.exists():
            return
        try:
            bank, experiments = load_checkpoint(path)
        except Exception as exc:  # a damaged checkpoint is only a cache: the log rebuilt it
            self.get_logger().warning(f"ignoring unreadable checkpoint {path}: {exc}")
            return
        if experiments == replayed and np.allclose(bank.w, self.bank.w, atol=1e-9):
            return
        self.get_logger().warning(
            f"checkpoint has {experiments} experiments, the log {replayed}: the log wins"
        )

    def _start_once(self) -> None:
        self._start_timer.cancel()
        self._thread = threading.Thread(target=self._run, name="experiments", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)

    def destroy_node(self) -> None:
        self.stop()
        super().destroy_node()

    @property
    def experiments(self) -> int:
        return len(self.log)

    # -- the loop ------------------------------------------------------------------------

    def _run(self) -> None:
        failures = 0
        while not self._stop.is_set() and self.context.ok():
            if self.max_experiments and self.experiments >= self.max_experiments:
                self.get_logger().info(f"done: {self.experiments} experiments")
                break
            try:
                self._one_experiment()
                failures = 0
            except (PlacementUnavailable, ExperimentAborted, TimeoutError) as exc:
                failures += 1
                self._dropped += 1
                self.get_logger().warning(f"experiment dropped ({failures} in a row): {exc}")
                self._maybe_reset(force=failures >= 3)
                if failures >= 3:
                    failures = 0
                self._stop.wait(min(0.2 * failures, 2.0))
            except Exception as exc:  # never die silently on the experiment thread
                self.get_logger().error(f"unexpected error, stopping the loop: {exc!r}")
                break
        self.finished.set()

    def _one_experiment(self) -> None:
        start = time.perf_counter()
        before = self.world.blocks_count()
        self.world.wait_for_blocks()
        with self._lock:
            step = self.explorer.step()
        execution = self.world.last
        execution.stage_s["experiment_s"] = time.perf_counter() - start
        execution.stage_s["dropped_before"] = float(self._dropped)
        self._dropped = 0
        record = self._record(step, execution)
        self.log.append(record)
        save_checkpoint(self.run_dir / CHECKPOINT_NAME, self.bank, self.experiments)
        self._done_this_session += 1
        self.publish_experience(record, execution)
        self.publish_state()
        self.publish_markers(execution, step)
        minutes = (time.monotonic() - self._started_at) / 60.0
        self.get_logger().info(
            f"experiment {record['index']}: {record['mode']} h={record['state']} "
            f"a={record['action']} label={record['label']:+d} block={record['moved_block']} "
            f"({self._done_this_session / max(minutes, 1e-9):.1f}/min)"
        )
        # the memory must have taken this experiment into account before the next observation
        self.world.wait_for_blocks(newer_than=max(before, self.world.blocks_count()))
        # A scene that offers nothing but the table (say, a stack whose top is beyond reach
        # and one loose block) cannot teach anything: have it reset, as a person would.
        self._table_only = self._table_only + 1 if execution.available == [0] else 0
        limit = self.get_parameter("stuck_reset").value
        self._maybe_reset(force=bool(limit) and self._table_only >= limit,
                          why="only the table offered")

    def _maybe_reset(self, force: bool = False, why: str = "repeated failures") -> None:
        away = self.world.blocks_out_of_reach()
        if not away and not force:
            return
        self._table_only = 0
        reason = f"blocks out of reach: {', '.join(away)}" if away else why
        try:
            message = self.world.reset()
            self.get_logger().info(f"reset the world ({reason}): {message}")
        except (TimeoutError, ExperimentAborted) as exc:
            self.get_logger().warning(f"could not reset the world ({reason}): {exc}")

    def _record(self, step, execution) -> dict:
        inst = execution.instance
        weights_after = self.bank.weights(step.state)
        return {
            "index": self.experiments,
            "setting": execution.setting,
            "available": execution.available,
            "mode": MODE_NAMES[step.mode],
            "state": step.state,
            "action": step.action + 1,
            "action_index": step.action,
            "label": step.label,
            "moved_block": execution.moved_block,
            "attempts": execution.attempts,
            "instance": {
                "pixel_u": inst.pixel_u,
                "pixel_v": inst.pixel_v,
                "bits": [bool(b) for b in inst.bits],
                "features": list(inst.features),
                "support_ids": list(inst.support_ids),
                "placement": [
                    inst.placement.position.x,
                    inst.placement.position.y,
                    inst.placement.position.z,
                ],
            },
            "margin_before": step.margin_before,
            "confidence_before": step.chi_before,
            "weights_before": step.weights_before.tolist(),
            "weights_after": weights_after.tolist(),
            "stage_s": {k: round(v, 4) for k, v in execution.stage_s.items()},
            "wall_time": time.time(),
        }

    # -- publishing ----------------------------------------------------------------------

    def publish_experience(self, record: dict, execution) -> None:
        msg = Experience()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = self.frame_id
        msg.index = record["index"]
        msg.setting = record["setting"]
        msg.mode = record["mode"]
        msg.instance = execution.instance
        msg.moved_block = record["moved_block"]
        msg.label = record["label"]
        msg.margin_before = float(record["margin_before"])
        msg.confidence_before = float(record["confidence_before"])
        msg.weights_before = [float(v) for v in record["weights_before"]]
        msg.weights_after = [float(v) for v in record["weights_after"]]
        self.experience_pub.publish(msg)

    def publish_state(self) -> None:
        msg = LearnerState()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = self.frame_id
        msg.experiments = self.experiments
        msg.queries = sum(r.get("mode") == "query" for r in self.log.records)
        msg.plans = sum(r.get("mode") == "plan" for r in self.log.records)
        msg.strategy = self.strategy_name
        msg.alpha = float(self.rule.alpha)
        msg.theta = float(self.rule.theta)
        for h in range(self.max_height + 1):
            k = self.bank.slot[h]
            msg.heights.append(
                HeightModel(
                    height=h,
                    examples=int(self.bank.examples[k]),
                    weights=[float(v) for v in self.bank.w[k]],
                    margins=[float(v) for v in self.bank.margin[h]],
                    confidence=[float(v) for v in self.bank.chi[h]],
                    unknown=[bool(v) for v in self.bank.unknown[h]],
                )
            )
        self.state_pub.publish(msg)

    def publish_markers(self, execution, step) -> None:
        inst = execution.instance
        stamp = self.get_clock().now().to_msg()
        colour = (
            ColorRGBA(r=0.1, g=0.8, b=0.1, a=0.9)
            if step.label > 0
            else ColorRGBA(r=0.9, g=0.1, b=0.1, a=0.9)
        )
        place = Marker(ns="placement", id=0, type=Marker.SPHERE, action=Marker.ADD)
        place.header.frame_id, place.header.stamp = self.frame_id, stamp
        place.pose = inst.placement
        place.scale.x = place.scale.y = place.scale.z = 0.02
        place.color = colour
        place.lifetime = Duration(sec=0)
        text = Marker(ns="placement", id=1, type=Marker.TEXT_VIEW_FACING, action=Marker.ADD)
        text.header.frame_id, text.header.stamp = self.frame_id, stamp
        text.pose.position = Point(
            x=inst.placement.position.x,
            y=inst.placement.position.y,
            z=inst.placement.position.z + 0.05,
        )
        text.scale.z = 0.02
        text.color = colour
        text.text = (
            f"#{self.experiments - 1} {MODE_NAMES[step.mode]} s={step.state} "
            f"a={step.action + 1} y={step.label:+d}"
        )
        self.marker_pub.publish(MarkerArray(markers=[place, text]))

    def _on_save(self, request, response):
        with self._lock:
            save_checkpoint(self.run_dir / CHECKPOINT_NAME, self.bank, self.experiments)
        response.success = True
        response.message = (
            f"saved {self.experiments} experiments to {self.run_dir / CHECKPOINT_NAME}"
        )
        return response


def main(args: list[str] | None = None) -> int:
    rclpy.init(args=args)
    try:
        node = CuriosityNode()
    except Exception as exc:  # invalid parameters: say which, and stop
        print(f"curiosity_node: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 1
    executor = MultiThreadedExecutor()
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.stop()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
