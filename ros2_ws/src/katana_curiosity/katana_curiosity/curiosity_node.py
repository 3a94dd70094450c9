"""curiosity_node: the paper's exploration loop on the (simulated or real) arm.

Drives the core explorer through RobotEnvironment and core.robot_loop. After every experiment
the loop appends the ExperimentRecord to experience.jsonl (flushed and fsynced) and this node
checkpoints the learner and publishes curiosity/experience, curiosity/learner_state and
curiosity/markers. Started on a run folder that already has a log, it replays the log and
carries on: nothing recorded is lost and no experiment is counted twice. alpha, theta, gamma
and strategy apply live (`ros2 param set`); every other parameter is read-only.
"""

from __future__ import annotations

import sys
import threading
import time
from collections import Counter
from functools import partial
from pathlib import Path

import numpy as np
from katana_common.diagnostics import Diagnostics
from katana_common.executor import MultiThreadedExecutor
from katana_common.health import ERROR, OK, WARN, Health, RateMeter
from katana_common.node_runner import run_node
from katana_common.params import ParameterError, declare_parameters
from katana_common.qos import EVENT_QOS, STATE_QOS
from katana_interfaces.msg import Experience, LearnerState
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from .core.explorer import Explorer
from .core.robot_loop import (
    LoopPolicy,
    RobotLoop,
    Stopping,
    feasible_actions,
    robot_bank,
    set_query_rule,
)
from .core.run_record import (
    CHECKPOINT_NAME,
    LOG_NAME,
    ExperienceLog,
    LogError,
    check_checkpoint,
    replay,
    save_checkpoint,
)
from .core.strategies import make_strategy
from .messages import experience_msg, learner_state_msg, markers_msg
from .node_params import PARAMS, cross_check, environment_config
from .robot_environment import RobotEnvironment


class CuriosityNode(Node):
    """Curiosity learner and planner (paper sections 2.3-2.6) as a ROS 2 node."""

    def __init__(self, **kwargs) -> None:
        super().__init__("curiosity_node", **kwargs)
        self.params = p = declare_parameters(self, PARAMS, cross_check)
        self.strategy_name, self.max_height = p["strategy"], p["max_height"]
        self.n_actions, self.frame_id = p["n_actions"], p["world_frame"]
        self.run_dir = Path(p["run_dir"])
        self.bank = robot_bank(self.max_height, self.n_actions, p["alpha"], p["theta"])
        self.rule = self.bank.rule
        try:
            self.log = ExperienceLog(self.run_dir / LOG_NAME, p["quarantine_bad_lines"])
            replayed = replay(self.bank, self.log.records, str(self.run_dir / LOG_NAME))
        except (LogError, OSError) as exc:
            raise ParameterError(
                f"parameter 'run_dir': cannot resume: {exc} (parameter 'quarantine_bad_lines' "
                "true, katana-demo --quarantine-bad-lines, moves bad lines to a side file and "
                "resumes)" if isinstance(exc, LogError) else
                f"parameter 'run_dir': cannot resume: {exc}") from None
        if self.log.moved_aside:
            aside, size = self.log.moved_aside
            self.get_logger().warning(f"moved a torn last line ({size} bytes) aside to {aside}")
        if self.log.quarantined:
            lines = "; ".join(f"line {n}: {why}" for n, why in self.log.quarantined)
            self.get_logger().warning(
                f"quarantined {len(self.log.quarantined)} bad line(s) of {self.log.path} to "
                f"{self.log.quarantine_path} ({lines}); the log as it was is kept as "
                f"{self.log.original_path}; resuming with {len(self.log)} experiments")
        self._check_checkpoint()
        self._modes = Counter(r.mode for r in self.log.records)  # for learner_state
        self._stop = threading.Event()
        self.finished = threading.Event()
        group = ReentrantCallbackGroup()
        self.environment = RobotEnvironment(self, environment_config(p), self._stop,
                                            callback_group=group)
        self.environment.settings_observed = self.log.records[-1].setting if self.log else 0
        self.explorer = Explorer(self.environment, self.bank, self._make_strategy(),
                                 record_weights=True)
        self.explorer.steps = replayed
        self.loop = RobotLoop(
            self.environment, self.explorer, self.log,
            LoopPolicy(max_experiments=p["max_experiments"], stuck_reset=p["stuck_reset"],
                       setting_changes=p["setting_changes"],
                       stop_when_all_known=p["stop_when_all_known"],
                       unrealisable_after=p["unrealisable_after"]),
            self._publish_experiment, self.get_logger(), self._stop)
        self.experience_pub = self.create_publisher(Experience, "curiosity/experience", EVENT_QOS)
        self.state_pub = self.create_publisher(LearnerState, "curiosity/learner_state", STATE_QOS)
        self.marker_pub = self.create_publisher(MarkerArray, "curiosity/markers", EVENT_QOS)
        self.create_service(Trigger, "~/save", self._on_save,
                            callback_group=MutuallyExclusiveCallbackGroup())
        self._pending: dict = {}
        self._pending_lock = threading.Lock()
        p.on_change(self._on_live_change)
        self._thread: threading.Thread | None = None
        self._phase = Health(OK, "starting")
        self._rate = RateMeter(window_s=60.0)
        self.diagnostics = Diagnostics(self, {"experiments": self.health})
        self.publish_state()
        self.get_logger().info(
            f"strategy {self.strategy_name}, heights 0..{self.max_height}, {self.n_actions} "
            f"actions, alpha {self.rule.alpha}, theta {self.rule.theta}; run folder "
            f"{self.run_dir} ({replayed} experiments replayed)")
        self._start_timer = self.create_timer(0.0, self._start_once)

    def _make_strategy(self):
        # seeded by the run's position, so a resumed run goes on as one uninterrupted run would
        return make_strategy(
            self.params["strategy"], self.bank, self.max_height + 1, self.params["gamma"],
            seed=self.params["seed"] + len(self.log),
            feasible=feasible_actions(self.max_height, self.n_actions,
                                      self.params["table_action"]))

    def _check_checkpoint(self) -> None:
        verdict = check_checkpoint(
            self.run_dir / CHECKPOINT_NAME, self.log.records,
            lambda: robot_bank(self.max_height, self.n_actions, self.params["alpha"],
                               self.params["theta"]))
        if verdict.message:
            self.get_logger().warning(verdict.message)

    # -- lifecycle -----------------------------------------------------------------------

    def _start_once(self) -> None:
        self._start_timer.cancel()
        self._started_at = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="experiments", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            if not self.loop.finished_all:
                self._phase = Health(WARN, "waiting for the arm and the graph")
                self.environment.wait_until_ready(self.params["ready_timeout_s"])
                self.get_logger().info("the arm and the graph are ready")
            self._phase = Health(OK, "running")
            why = self.loop.run()
            self._phase = Health(OK, why)
            self.get_logger().info(why)
            self.publish_state()  # the last state, with all_known_at when that ended the run
        except Stopping:
            self._phase = Health(OK, "stopped")
        except TimeoutError as exc:
            self._phase = Health(ERROR, f"not starting: {exc}")
            self.get_logger().error(self._phase.message)
        except Exception as exc:  # never die silently on the experiment thread
            self._phase = Health(ERROR, f"the experiment loop stopped: {exc!r}")
            self.get_logger().error(self._phase.message)
        finally:
            self.finished.set()

    def health(self) -> Health:
        """/diagnostics: how the run goes (experiments per minute of wall time, attempts
        dropped this session by reason, pairs still unknown)."""
        unknown = self.loop.unknown_realisable_pairs()
        left = self.bank.unknown if unknown is None else unknown
        return Health(self._phase.level, self._phase.message, {
            "experiments": self.experiments,
            "experiments_per_min": 60.0 * self._rate.per_second(),
            "dropped": sum(self.loop.dropped_total.values()),
            **{f"dropped_{k}": v for k, v in sorted(self.loop.dropped_total.items())},
            "resets": self.loop.resets,
            "unknown_pairs_left": int(np.count_nonzero(left)),
            "all_known_at": self.loop.all_known_at,
        })

    def stop(self) -> None:
        """End every wait at once and the experiment thread (the log is fsynced per record)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=1.5)

    def destroy_node(self) -> None:
        self.stop()
        super().destroy_node()

    @property
    def experiments(self) -> int:
        return len(self.log)

    # -- live parameters -----------------------------------------------------------------

    def _on_live_change(self, changed: dict) -> None:
        with self._pending_lock:
            self._pending.update(changed)
        if self.loop.lock.acquire(blocking=False):  # else: applied after this experiment
            try:
                self._apply_pending()
            finally:
                self.loop.lock.release()
            self.publish_state()

    def _apply_pending(self) -> None:
        """Apply accepted live changes; called with the loop's lock held."""
        with self._pending_lock:
            changed, self._pending = self._pending, {}
        if not changed:
            return
        if "alpha" in changed or "theta" in changed:
            set_query_rule(self.bank, self.params["alpha"], self.params["theta"])
            self.rule = self.bank.rule
        if "strategy" in changed or "gamma" in changed:
            self.strategy_name = self.params["strategy"]
            self.explorer.strategy = self._make_strategy()

    # -- publishing ----------------------------------------------------------------------

    def _publish_experiment(self, record, step) -> None:
        self._modes[record.mode] += 1
        with self.loop.lock:
            self._apply_pending()
        try:
            self._checkpoint()
        except OSError as exc:  # a cache only: the log (already written) is the record
            self.get_logger().warning(f"checkpoint not saved: {exc}")
        stamp = self.get_clock().now().to_msg()
        instance = step.record.message
        self.experience_pub.publish(experience_msg(record, instance, stamp, self.frame_id))
        self.publish_state()
        self.marker_pub.publish(markers_msg(record, instance, stamp, self.frame_id))
        self._rate.tick()
        rate = self.loop.done_this_session / max(time.monotonic() - self._started_at, 1e-9) * 60
        self.get_logger().info(
            f"experiment {record.index}: {record.mode} h={record.state} a={record.action} "
            f"label={record.label:+d} block={record.moved_block} ({rate:.1f}/min)")

    def publish_state(self) -> None:
        self.state_pub.publish(learner_state_msg(
            self.bank, self._modes, self.strategy_name, self.max_height,
            self.get_clock().now().to_msg(), self.frame_id, self.loop.all_known_at))

    def _checkpoint(self) -> str:
        path = self.run_dir / CHECKPOINT_NAME
        with self.loop.lock:
            save_checkpoint(path, self.bank, self.experiments)
        return f"saved {self.experiments} experiments to {path}"

    def _on_save(self, _request, response):
        try:
            response.message = self._checkpoint()
            response.success = True
        except Exception as exc:  # folder gone, disk full: answer, never end the node
            response.success = False
            response.message = f"could not save to {self.run_dir}: {exc}"
            self.get_logger().error(response.message)
        return response


def main(args: list[str] | None = None) -> int:
    return run_node(CuriosityNode, "curiosity_node", args,
                    executor_factory=partial(MultiThreadedExecutor, num_threads=4))


if __name__ == "__main__":
    sys.exit(main())
