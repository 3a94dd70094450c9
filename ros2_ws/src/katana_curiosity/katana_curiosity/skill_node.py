"""skill_node: the stacking skill (paper Figure 14) as the `build_stack` action.

Thin: the plan and the choices are core.skill's (the MDP of section 2.4 on the learned
transitions, a reward for reaching the target height, falls absorbing); the placements go
through the graph like the curiosity node's (fovea/observe, pick_and_place,
perception/judge_placement, memory/blocks) via RobotEnvironment. The node only uses the learned
model loaded from a run's learner.npz (parameter `model`; '' = an untrained model, every
placement predicted at even odds) and learns nothing. One goal at a time; after every judged
placement it publishes feedback with the predicted and the observed outcome, observes the
setting again and chooses anew.

Parameters: `model` and `max_placements`, and node_params.ROBOT_PARAMS, declared as
curiosity_node declares them (one definition, one default: the state-action space, gamma,
the graph calls and their timeouts, reset_service, the scene and the pick-and-place geometry
the reach comes from). gamma applies to the next goal (live); the rest is read-only.
"""

from __future__ import annotations

import sys
import threading
from functools import partial
from pathlib import Path

import numpy as np
from katana_common.executor import MultiThreadedExecutor
from katana_common.node_runner import run_node
from katana_common.params import Param, ParameterError, declare_parameters
from katana_interfaces.action import BuildStack
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node

from .core.robot_loop import ExperimentAborted, Stopping, Unrealisable
from .core.run_record import CHECKPOINT_NAME, load_checkpoint
from .core.skill import (
    LearnedModel,
    SkillOutcome,
    SkillWorld,
    StackingSkill,
    build_stack,
    choose_base,
)
from .node_params import ROBOT_PARAMS, cross_check, environment_config, place_reach_of
from .robot_environment import RobotEnvironment

PARAMS = (
    Param("model", "", "A run folder (its learner.npz) or a learner.npz; '' = untrained."),
    Param("max_placements", 12, "Default bound on placements per goal.", 1, 1000),
    *ROBOT_PARAMS,
)

_RESULT = BuildStack.Result
#: attempts that placed nothing (a slip, no block to move) before the goal is given up
MAX_NOT_MADE = 3


def load_model(path: str, max_height: int, n_actions: int) -> LearnedModel:
    """The learned margins of a run (its learner.npz); zeros (even odds) for ''."""
    if not path:
        return LearnedModel.from_margins(np.zeros((max_height + 2, n_actions)))
    file = Path(path)
    if file.is_dir():
        file = file / CHECKPOINT_NAME
    bank, _ = load_checkpoint(file)
    if bank.n_actions != n_actions or bank.n_states < max_height + 1:
        raise ValueError(f"{file} models {bank.n_states} states x {bank.n_actions} actions, "
                         f"the node needs {max_height + 1} x {n_actions}")
    return LearnedModel.from_bank(bank)


class _Canceled(Exception):
    pass


class GraphSkillWorld(SkillWorld):
    """core.skill's world over RobotEnvironment: settings from the fovea, placements through
    pick_and_place and the judge, the highest stack from memory/blocks."""

    def __init__(self, env: RobotEnvironment, canceled, target_height: int,
                 place_reach_m: tuple[tuple[float, float], ...]) -> None:
        self.env, self.canceled = env, canceled
        self.target_height, self.place_reach_m = target_height, place_reach_m
        self.setting = None
        self.not_made: list[str] = []  # why attempts placed nothing

    def offered(self) -> list[tuple[int, int]]:
        if self.canceled():
            raise _Canceled
        self.env.wait_until_current()
        try:
            setting = self.setting = self.env.observe()
        except Unrealisable:
            return []
        return sorted({(int(s), int(a) + 1) for s, a in zip(setting.states, setting.actions,
                                                            strict=True)})

    def place(self, state: int, action: int) -> int:
        if self.canceled():
            raise _Canceled
        # an observed instance (it has a block to move), not a new fovea search
        index = self._instance_index(state, action)
        try:
            outcome = self.env.execute(state, action - 1, index)
        except (ExperimentAborted, Unrealisable) as exc:
            # nothing placed (a slip, no block to move): observe again, within the bound
            self.not_made.append(str(exc))
            if len(self.not_made) > MAX_NOT_MADE:
                raise
            return 0
        finally:
            self.env.mark_scene_changed()
        return int(outcome.label)

    def _instance_index(self, state: int, action: int) -> int | None:
        """Of the observed instances of (state, action), the one on the stack to build on."""
        if self.setting is None:
            return None
        hits = self.setting.indices_of(state, action - 1)
        if not len(hits):
            return None
        where = [(self.env.instances[i].placement.position.x,
                  self.env.instances[i].placement.position.y) for i in hits]
        return int(hits[choose_base(where, state, self.target_height, self.place_reach_m)])

    def highest_stack(self) -> int:
        blocks = self.env.wait_for_blocks()
        return max((int(b.level) for b in blocks.blocks), default=0)


class SkillNode(Node):
    """Serves build_stack with the learned model only."""

    def __init__(self, **kwargs) -> None:
        super().__init__("skill_node", **kwargs)
        self.params = p = declare_parameters(self, PARAMS, cross_check)
        try:
            self.model = load_model(p["model"], p["max_height"], p["n_actions"])
        except (OSError, ValueError, KeyError) as exc:
            raise ParameterError(f"parameter 'model': cannot load {p['model']!r}: {exc}") from None
        self._stop = threading.Event()
        self._busy = threading.Lock()
        group = ReentrantCallbackGroup()
        self.environment = RobotEnvironment(self, environment_config(p), self._stop,
                                            callback_group=group)
        self.place_reach_m = place_reach_of(p)
        self._ready = False
        self.server = ActionServer(
            self, BuildStack, "build_stack", execute_callback=self._execute,
            goal_callback=lambda _goal: GoalResponse.ACCEPT,
            cancel_callback=lambda _handle: CancelResponse.ACCEPT, callback_group=group)
        self.get_logger().info(
            f"build_stack ready: model {p['model'] or 'untrained'}, heights "
            f"0..{p['max_height']}, {p['n_actions']} actions")

    def stop(self) -> None:
        self._stop.set()

    def _execute(self, handle):
        goal = handle.request
        result = BuildStack.Result()
        if not self._busy.acquire(blocking=False):
            return self._end(handle, result, _RESULT.INVALID_GOAL,
                             "another build_stack goal is active")
        try:
            return self._build(handle, goal, result)
        finally:
            self._busy.release()

    def _build(self, handle, goal, result):
        top = self.model.margin.shape[0]
        if not 1 <= goal.target_height <= min(top, self.params["max_height"] + 1):
            return self._end(handle, result, _RESULT.INVALID_GOAL,
                             f"target_height {goal.target_height} outside 1.."
                             f"{min(top, self.params['max_height'] + 1)}")
        bound = goal.max_placements or self.params["max_placements"]
        skill = StackingSkill(self.model, int(goal.target_height), self.params["gamma"],
                              self.params["table_action"])
        world = GraphSkillWorld(self.environment, lambda: handle.is_cancel_requested,
                                int(goal.target_height), self.place_reach_m)
        made: list[SkillOutcome] = []  # judged placements, also when the goal ends early
        try:
            if not self._ready:
                self.environment.wait_until_ready(self.params["ready_timeout_s"])
                self._ready = True
            outcome = build_stack(world, skill, bound, partial(self._feedback, handle, made))
        except (_Canceled, Stopping, ExperimentAborted, Unrealisable, TimeoutError) as exc:
            result.placements = len(made)
            result.falls = sum(1 for o in made if o.label < 0)
            return self._ended_early(handle, result, world, exc)
        result.height_reached = int(outcome.height)
        result.placements = len(outcome.placements)
        result.falls = outcome.falls
        code = {"reached": _RESULT.SUCCESS, "no placement offered": _RESULT.NO_PLACEMENT}.get(
            outcome.reason, _RESULT.PLACEMENT_BOUND)
        result.success = outcome.reached
        result.error_code, result.reason = code, outcome.reason
        (handle.succeed if outcome.reached else handle.abort)()
        self.get_logger().info(
            f"build_stack {goal.target_height}: {outcome.reason}, height {outcome.height}, "
            f"{len(outcome.placements)} placements, {outcome.falls} falls")
        return result

    def _ended_early(self, handle, result, world: GraphSkillWorld, exc: Exception):
        if isinstance(exc, _Canceled):
            handle.canceled()
            result.error_code, result.reason = _RESULT.CANCELED, "canceled"
            return result
        if isinstance(exc, Stopping):
            return self._end(handle, result, _RESULT.CANCELED, str(exc))
        if self._ready:  # the memory has published: the height it says
            try:
                result.height_reached = world.highest_stack()
            except (TimeoutError, Stopping):
                pass
        return self._end(handle, result, _RESULT.EXECUTION_FAILED, str(exc))

    @staticmethod
    def _end(handle, result, code: int, reason: str):
        result.success, result.error_code, result.reason = False, code, reason
        handle.abort()
        return result

    @staticmethod
    def _feedback(handle, made: list[SkillOutcome], outcome: SkillOutcome) -> None:
        made.append(outcome)
        handle.publish_feedback(BuildStack.Feedback(
            placement=len(made), state=outcome.choice.state, action=outcome.choice.action,
            predicted_success=outcome.choice.predicted_success,
            planned_value=outcome.choice.value, observed_label=int(outcome.label),
            height_after=int(outcome.height_after)))


def main(args: list[str] | None = None) -> int:
    return run_node(SkillNode, "skill_node", args,
                    executor_factory=partial(MultiThreadedExecutor, num_threads=4))


if __name__ == "__main__":
    sys.exit(main())
