"""The experiment loop on the (simulated or real) arm, without ROS: one experiment after the
other, the log written before the next starts, and the policy for what goes wrong.

Policy (the paper's robot had a person for this; here it is explicit):
- An attempt that cannot be completed (no usable instance, no block the arm can move, a
  missed grasp given up, a slip, a time-out) is *dropped*: nothing is learned or logged, and
  the reason is counted in the next record's `dropped_before`.
- After `failures_before_reset` drops in a row, or when a block lies out of reach, or when
  `stuck_reset` experiments in a row offered only the table, the environment is reset. A
  setting that offers no usable instance is reset at once: nothing has moved, so observing it
  again offers nothing again.
- No experiment wasted: a planned placement whose outcome the learner already knows is made
  only if it leads towards an unknown pair (`leads_towards_unknown`); otherwise the setting
  is changed (reset) instead, at most `setting_changes` times since the last experiment that
  taught the learner (or the last plan so followed) before the plan is followed anyway (a
  setting that no reset improves must not stop the run, nor a cycle of a known placement and
  a reset).
- A known plan made before in the same scene is made again only while a scene it led to, or
  one reachable from there by placements made before (as many as the deepest plan, never back
  into the scenes since the last experiment that taught the learner), offers a pair unknown now
  (`progress.PlanOutcomes`: not if it changed nothing, closed a cycle or ended in scenes of
  known pairs), and no known plan once as many known plans as the deepest plan were made
  since the last experiment that taught the learner (`detour_too_long`); nor is a table placement
  that could only move a loose block; nor a known placement on a stack that would leave too
  few movable blocks to reach the next unknown height (`progress.blocks_short`:
  `too_few_blocks`), nor a known table placement in a setting that already offers a stack of
  one to build on (`table_beside_a_base`: it lowers a stack for a base that is there), nor a
  known placement that makes a stack standing outside the place reach of a height it is to
  be built up to (`goal_out_of_reach`: the fovea offers nothing on its top there). The
  best other plan worth making is made instead, and only when there is none is the setting
  changed (within the same `setting_changes` bound).
- A pair never offered in `unrealisable_after` logged settings offering its height is one the
  arm does not realise (`progress.Realisability`): the planner puts no phantom reward on it.
- When no pair the arm can realise is unknown, the loop says so once and, if
  `stop_when_all_known`, ends: the paper's agent "knows when to stop its planning efforts".
  Otherwise it follows its plans without changing the setting (no setting has anything
  unknown to offer), refining the model as the paper's agent does once everything is known.
- Every wait watches `stop`, so `stop.set()` ends the loop at once.
Choices depend only on the seed and on what the environment reports, never on wall time.
"""

from __future__ import annotations

import math
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np

from .environment import Environment, PlacementUnavailable
from .explorer import MODE_NAMES, Choice, Explorer, NoRouteToUnknown, Step, Strategy
from .planner import clip_margin
from .predictors import PredictorBank, QueryRule, one_hot_with_bias
from .progress import (
    Offer,
    PlanOutcomes,
    Realisability,
    blocks_short,
    offer_of,
    taught,
    unknown_offered,
    unknown_realisable,
)
from .run_record import ExperienceLog, ExperimentRecord, InstanceRecord


def robot_bank(max_height: int, n_actions: int, alpha: float, theta: float) -> PredictorBank:
    """The robot's learner: heights 0..max_height, one-hot actions with a bias."""
    return PredictorBank(range(max_height + 1), one_hot_with_bias(n_actions),
                         QueryRule(alpha, theta), n_states=max_height + 2)


#: the fovea's probe points (centre and four corners): actions are 1 + the points on the block
FOVEA_POINTS = 5


def feasible_actions(max_height: int, n_actions: int, table_action: int) -> np.ndarray:
    """(states, actions) table of what can ever occur: on the table only `table_action`; on a
    single block, for the five-point fovea, not action 5 (all points but one corner on it).
    The fovea turns with the block it looks at, so block and probe square are aligned, and an
    aligned rectangle holding three corners of a square holds the fourth. On a stack the
    intersection of turned top faces is not aligned, and action 5 occurs (rarely)."""
    feasible = np.ones((max_height + 2, n_actions), dtype=bool)
    if table_action:
        feasible[0] = False
        feasible[0, table_action - 1] = True
    if n_actions == FOVEA_POINTS + 1 and max_height >= 1:
        feasible[1, FOVEA_POINTS - 1] = False
    return feasible


#: the action only a stack whose top faces are turned against each other offers (1-based)
TURNED_ACTION = FOVEA_POINTS
#: a block placed to make a stack that is to offer TURNED_ACTION is turned by this against the
#: one below: on the fovea, stacks of three with a top turned 5 degrees or more offered every
#: action in 30 of 30, where square ones (2 mm and 0.6 degrees of placement error) offered
#: action 5 in 14
BUILD_TURN_RAD = math.radians(10.0)


def build_turn(bank: PredictorBank, unknown: np.ndarray | None, choice: Choice,
               goal: int | None) -> float:
    """How far to turn the block of a planned placement against the one below: BUILD_TURN_RAD
    for a known placement on a stack that makes the stack of the plan's goal height when
    TURNED_ACTION is the only pair unknown there (`unknown`: the unknown pairs the arm can
    realise), else 0. A stack built square offers that action only by the arm's placement
    error, so a plan building towards it would be made again and again; while any other pair
    there is unknown, every stack of that height offers something to learn, and stacks are
    built square as the truth table's were. A query is placed as the fovea offers it (its
    outcome is what is learned)."""
    s, a = choice.state, choice.action
    if (unknown is None or goal is None or s < 1 or goal != s + 1 or goal >= len(unknown)
            or bank.unknown[s, a]):
        return 0.0
    alone = bool(unknown[goal, TURNED_ACTION - 1]) and int(unknown[goal].sum()) == 1
    return BUILD_TURN_RAD if alone else 0.0


def set_query_rule(bank: PredictorBank, alpha: float, theta: float) -> None:
    """Apply a new alpha / theta (Eq. 2) to a learning bank: its confidences and query flags
    are recomputed, the weights are untouched."""
    bank.rule = QueryRule(alpha, theta)
    for height in bank.heights:
        bank._refresh(int(height))  # the bank's own recomputation of chi and the flags


#: a successor height whose best value is at most this has no phantom reward within reach
NO_VALUE = 1e-6


def leads_towards_unknown(strategy: Strategy, choice: Choice) -> bool:
    """Whether a planned placement is worth making: its pair is still unknown, or the learner
    predicts it stays (margin > 0) and the stack it grows has an unknown pair within the plan's
    reach (V(s+1) > 0). When nothing is unknown anywhere, no setting can do better: True."""
    planner = getattr(strategy, "planner", None)
    if planner is None:
        return True
    bank, s, a = strategy.bank, choice.state, choice.action
    unknown = bank.unknown[: planner.top]
    if planner.feasible is not None:
        unknown = unknown & planner.feasible[: planner.top]
    if not unknown.any() or bank.unknown[s, a]:
        return True
    up = s + 1
    return bool(clip_margin(bank.margin[s, a]) > 0.0 and up < planner.top
                and planner.q[up].max() > NO_VALUE)


class ExperimentAborted(RuntimeError):
    """The experiment could not be completed; nothing is learned from it. `reason` is a short
    code for the counts in summary.json (e.g. grasp_missed, block_slipped, no_verdict)."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


class Unrealisable(PlacementUnavailable):
    """PlacementUnavailable with a reason code (no_usable_instance, no_block_to_move, ...)."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


class Stopping(RuntimeError):
    """The loop is stopping: a wait ended early."""


def drop_reason(exc: BaseException) -> str:
    """The reason code of a dropped attempt."""
    reason = getattr(exc, "reason", None)
    if reason:
        return str(reason)
    if isinstance(exc, PlacementUnavailable):
        return "placement_unavailable"
    if isinstance(exc, TimeoutError):
        return "timeout"
    return type(exc).__name__


#: what to do after a failed pick-and-place, by the result's name (PickAndPlace.Result)
RETRY_SAME, TRY_ANOTHER, GIVE_UP, UNREALISABLE = "retry", "another", "give_up", "unrealisable"
#: the result names the policy knows (lower-case constants of PickAndPlace.Result)
POLICY_RESULTS = ("grasp_missed", "pick_unreachable", "place_unreachable")


def leave_until_moved(result: str, action: str) -> bool:
    """Whether a block whose pick-and-place failed so is left alone until it moves: one the arm
    cannot reach or keeps missing, and one that slipped out of the fingers and still lies
    where it was (a block leaning on another slips again: on the sim the loop picked such a
    block three times in a row, then asked for a reset)."""
    return action in (TRY_ANOTHER, GIVE_UP) and result in (*POLICY_RESULTS, "block_slipped")


#: failed pick-and-places after which the arm may have moved blocks (a grasp that missed, a block
#: that slipped, a move that stopped short, timed out or was aborted): the scene is looked at
#: again only in an image taken after the arm parked (RobotEnvironment.mark_scene_changed)
ARM_MOVED_RESULTS = ("grasp_missed", "block_slipped", "arm_did_not_reach", "timeout",
                     "aborted")


def after_failed_pick_place(result: str, attempts: int, retries: int) -> str:
    """The retry policy: a missed grasp is tried again (the paper's robot did), an unreachable
    pick tries another block, an unreachable place cannot be realised (a planner then tries
    its next choice); anything else, or `retries` used up, gives the attempt up."""
    if result == "place_unreachable":
        return UNREALISABLE
    if attempts > retries or result not in POLICY_RESULTS:
        return GIVE_UP
    return TRY_ANOTHER if result == "pick_unreachable" else RETRY_SAME


@dataclass
class ExecutionRecord:
    """What the robot environment did for one experiment (returned in `Outcome.record`)."""

    instance: InstanceRecord
    setting: int
    available: list[int]
    moved_block: str
    attempts: int
    stage_s: dict[str, float] = field(default_factory=dict)
    message: Any = None  # the environment's own form of the instance (a FoveaInstance)
    index: int | None = None  # the instance's index in the observed setting (None: found)


class RobotEnvironment(Environment, Protocol):
    """An Environment on an arm: it can be waited on, checked for reach and reset."""

    def wait_until_current(self) -> None:
        """Block until the environment's picture of the scene includes the last experiment."""
        ...

    def mark_scene_changed(self, experience: int | None = None) -> None:
        """Note that experiment `experience` is about to be published, or the world changed
        without one (None): the next wait_until_current awaits a picture of the scene taken
        after it."""
        ...

    def blocks_out_of_reach(self) -> list[str]: ...

    def reset(self) -> str: ...

    # optional: place_planned(setting, choice, target_height, turn_rad) -> choice, which
    # instance of a planned pair to make, its block turned by turn_rad against the fovea;
    # out_of_reach_for(choice, target_height) -> whether the stack that placement makes cannot
    # be built on up to target_height (no block can be placed on it there);
    # stack_heights() -> the heights of the stacks last observed;
    # moves_a_loose_block(choice) -> whether a table placement would move a loose block


#: why the loop changed the setting instead of making a planned placement (NoRouteToUnknown)
SETTING_CHANGES = frozenset({"no_route_to_unknown", "plan_leads_nowhere", "detour_too_long",
                             "table_to_table", "too_few_blocks", "table_beside_a_base",
                             "goal_out_of_reach"})

#: drops that leave the setting as it was: trying it again can only fail again
STILL_SETTING_REASONS = frozenset({"no_usable_instance"})


@dataclass(frozen=True)
class LoopPolicy:
    max_experiments: int = 0  # in total, over resumes (0: never stop)
    failures_before_reset: int = 3
    stuck_reset: int = 3  # experiments in a row offering only the table (0: never)
    backoff_s: float = 0.2  # pause after a drop, times the drops in a row
    max_backoff_s: float = 2.0
    setting_changes: int = 3  # pointless plans answered by a reset, until one teaches (0: never)
    stop_when_all_known: bool = True  # end the run once no pair the arm realises is unknown
    unrealisable_after: int = 30  # settings offering a height without a pair (0: never)


#: a known action within this of the plan's predicted margin counts as equally stable
SQUARE_MARGIN_SLACK = 0.1


def square_building(bank: PredictorBank, setting, choice: Choice) -> Choice:
    """A known placement made on the way to a higher unknown pair, made with the most test
    points on the support among the known actions the setting offers at that height that are
    about as stable (margin within SQUARE_MARGIN_SLACK of the plan's). The abstract plan cares
    only that the stack grows; the arm's next offer does not: the fovea offers on a stack's top
    only what the faces of the whole stack overlap, so a stack built off-centre never offers
    the actions of nearly full overlap (on the sim, a three-stack built with action 4 offered
    action 5 in one setting of ten)."""
    state, planned = choice.state, choice.action
    if bank.unknown[state, planned]:
        return choice  # a query is made as chosen
    floor = float(bank.margin[state, planned]) - SQUARE_MARGIN_SLACK
    offered = [a for a in range(bank.n_actions) if len(setting.indices_of(state, a))
               and not bank.unknown[state, a] and bank.margin[state, a] >= max(floor, 0.0)]
    best = max(offered, default=planned)
    if best <= planned:
        return choice
    return replace(choice, action=best, index=int(setting.indices_of(state, best)[0]))


class RobotLoop:
    """Runs experiments until done or stopped; `on_experiment(record, step)` publishes one."""

    def __init__(
        self,
        environment: RobotEnvironment,
        explorer: Explorer,
        log: ExperienceLog,
        policy: LoopPolicy,
        on_experiment: Callable[[ExperimentRecord, Step], None],
        logger: Any,
        stop: threading.Event | None = None,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        self.environment, self.explorer, self.log = environment, explorer, log
        self.policy, self.on_experiment, self.logger = policy, on_experiment, logger
        self.stop = stop or threading.Event()
        self.wall_clock = wall_clock
        self.lock = threading.Lock()  # held while the learner changes (save, live parameters)
        self.dropped: Counter[str] = Counter()  # since the last logged experiment
        self.dropped_total: Counter[str] = Counter()  # this session
        self.resets = 0
        self._table_only = 0
        # since the last experiment that taught the learner or the last plan followed anyway
        self._setting_changes = 0
        self.done_this_session = 0
        self.outcomes = PlanOutcomes(depth=explorer.bank.unknown.shape[0] - 1)
        self._offer: Offer = frozenset()
        self._scene: tuple = ()
        self._movable: int | None = None  # blocks the arm could move in the observed setting
        self._unknown_offered = -1
        self._resets_since_experiment = 0
        self.all_known_at: int | None = None  # experiments made when nothing was left unknown
        explorer.worth_making = self._worth_making
        explorer.on_setting = self._on_setting
        if hasattr(environment, "place_planned"):
            explorer.place_planned = self._place_planned
        planner = getattr(explorer.strategy, "planner", None)
        self.realisability: Realisability | None = None
        if planner is not None and planner.feasible is not None:
            self.realisability = Realisability(planner.feasible, policy.unrealisable_after)
            for record in log.records:  # what an uninterrupted run would have noted
                self.realisability.note(frozenset((h, a - 1) for h, a in record.offer))
            self._plan_on_realisable()

    def _plan_on_realisable(self) -> None:
        planner = getattr(self.explorer.strategy, "planner", None)  # a live strategy change
        if planner is None or planner.feasible is None:
            return
        table = self.realisability.table
        table[planner.top] = True
        if not np.array_equal(table, planner.feasible):
            planner.set_feasible(table)

    def _on_setting(self, setting) -> None:
        self._offer = offer_of(setting)
        stacks = getattr(self.environment, "stack_heights", lambda: ())()
        self._movable = getattr(self.environment, "movable_blocks", lambda: None)()
        # told apart by the heights offered, the stacks and how many blocks the arm could move
        # (a block on its side is a stack of one that is never moved: where a plan leads
        # depends on it), not by every action offered: the actions offered on a stack vary
        # with where exactly its top block came to rest, and a cycle through scenes that
        # differ only in that would go unnoticed
        self._scene = (frozenset(h for h, _ in self._offer), tuple(stacks))
        if self._movable is not None:
            self._scene += (self._movable,)
        self._unknown_offered = unknown_offered(self.explorer.bank, self._offer)
        if self.outcomes.observed(self._scene, self._offer):
            self.logger.info("the last placement left the setting as it was")

    def unknown_realisable_pairs(self) -> np.ndarray | None:
        """Unknown pairs the arm can realise (the planner plans on what it realises); None for
        a strategy that does not plan."""
        planner = getattr(self.explorer.strategy, "planner", None)
        if self.realisability is None or planner is None or planner.feasible is None:
            return None
        return unknown_realisable(self.explorer.bank, planner.feasible, planner.top)

    def _goal_above(self, height: int) -> int | None:
        """The lowest height above `height` where a pair the arm can realise is still unknown
        (the plan's next goal), or None."""
        unknown = self.unknown_realisable_pairs()
        if unknown is None:
            return None
        return next((h for h in range(height + 1, len(unknown)) if unknown[h].any()), None)

    def _place_planned(self, setting, choice: Choice) -> Choice:
        """The environment's choice of instance, towards the plan's next goal (`_goal_above`);
        a known placement that builds towards it is made square (`square_building`), and
        turned when the stack it makes is to offer TURNED_ACTION (`build_turn`)."""
        goal = self._goal_above(choice.state)
        if goal is None:
            return self.environment.place_planned(setting, choice, choice.state + 1, 0.0)
        choice = square_building(self.explorer.bank, setting, choice)
        turn = build_turn(self.explorer.bank, self.unknown_realisable_pairs(), choice, goal)
        return self.environment.place_planned(setting, choice, goal, turn)

    def _worth_making(self, strategy: Strategy, choice: Choice) -> str | None:
        """Why a planned placement is not to be made (the setting is changed instead), or
        None; a plan refused after `setting_changes` changes that taught nothing is made."""
        if not self.policy.setting_changes:
            return None  # setting changes are not wanted: follow the plan
        reason = self._refusal(strategy, choice)
        if reason and self._setting_changes >= self.policy.setting_changes:
            self._setting_changes = 0  # resets did not help: follow the plan, then count anew
            return None
        return reason

    def _refusal(self, strategy: Strategy, choice: Choice) -> str | None:
        if self.all_known_at is not None:
            return None  # nothing is left unknown: no setting offers more than this plan
        unknown = self.explorer.bank.unknown
        if not unknown[choice.state, choice.action]:
            goal = self._goal_above(choice.state)
            if goal is not None and getattr(self.environment, "out_of_reach_for",
                                            lambda *_: False)(choice, goal):
                return "goal_out_of_reach"
            if self.outcomes.detour_too_long:
                return "detour_too_long"
            if self.outcomes.leads_nowhere(self._scene, choice.state, choice.action, unknown):
                return "plan_leads_nowhere"
            if (self._movable is not None and goal is not None
                    and blocks_short(choice.state, goal, self._movable)):
                return "too_few_blocks"
            if choice.state == 0 and any(h == 1 for h, _ in self._offer):
                return "table_beside_a_base"
        if getattr(self.environment, "moves_a_loose_block", lambda _: False)(choice):
            return "table_to_table"  # a new stack of one where one already lies: no change
        return None if leads_towards_unknown(strategy, choice) else "no_route_to_unknown"

    def _built_out_of_reach(self, step: Step, execution: ExecutionRecord) -> bool:
        """Whether the experiment's block stayed where no block can be placed on the stack it
        made (`out_of_reach_for` that stack's own height)."""
        check = getattr(self.environment, "out_of_reach_for", None)
        if check is None or execution.index is None or step.label != 1:
            return False
        return bool(check(Choice(step.state, step.action, step.mode, execution.index),
                          step.state + 1))

    def _everything_known(self) -> bool:
        """Whether no pair the arm can realise is unknown (said once, in the log)."""
        unknown = self.unknown_realisable_pairs()
        if unknown is None or unknown.any():
            self.all_known_at = None
            return False
        if self.all_known_at is None:
            self.all_known_at = len(self.log)
            self.logger.info(f"every (height, action) pair the arm can realise is known after "
                             f"{len(self.log)} experiments")
        return True

    @property
    def finished_all(self) -> bool:
        return bool(self.policy.max_experiments) and len(self.log) >= self.policy.max_experiments

    def run(self) -> str:
        """Experiments until max_experiments or stop; returns why the loop ended."""
        try:
            return self._run()
        except Stopping:
            return "stopped"

    def _run(self) -> str:
        failures = 0
        while not self.stop.is_set():
            if self.finished_all:
                return f"done: {len(self.log)} experiments"
            if self._everything_known() and self.policy.stop_when_all_known:
                return (f"done: everything the arm can realise is known after {len(self.log)} "
                        "experiments")
            try:
                self.run_one()
                failures = 0
            except NoRouteToUnknown as exc:
                self._setting_changes += 1
                self.dropped[exc.reason] += 1
                self.dropped_total[exc.reason] += 1
                self.logger.info(f"changing the setting: {exc}")
                self.maybe_reset(force=True, why=exc.reason)
            except (PlacementUnavailable, ExperimentAborted, TimeoutError) as exc:
                failures += 1
                reason = drop_reason(exc)
                self.dropped[reason] += 1
                self.dropped_total[reason] += 1
                self.logger.warning(f"experiment dropped ({reason}, {failures} in a row): {exc}")
                still = reason in STILL_SETTING_REASONS
                force = still or failures >= self.policy.failures_before_reset
                self.maybe_reset(force=force, why=reason if still else
                                 f"{failures} failed attempts in a row")
                if force:
                    failures = 0
                self.stop.wait(min(self.policy.backoff_s * failures, self.policy.max_backoff_s))
        return "stopped"

    def run_one(self) -> ExperimentRecord:
        start = time.perf_counter()
        self.environment.wait_until_current()
        current_s = time.perf_counter() - start
        with self.lock:
            step = self.explorer.step()
            execution: ExecutionRecord = step.record
            execution.stage_s["current_s"] = current_s  # memory caught up with the last one
            execution.stage_s["experiment_s"] = time.perf_counter() - start
            record = self.make_record(step, execution)
            self.log.append(record)  # OSError ends the loop: nothing may go unrecorded
        self.done_this_session += 1
        taught_it = taught(record, self.explorer.bank.rule)
        if taught_it:
            # setting changes are counted until the learner learns: a known placement made
            # between two changes (a fresh scatter's base, built again and again) does not
            # end the count, or the bound would never be reached
            self._setting_changes = 0
        self._resets_since_experiment = 0
        self.dropped.clear()
        if self.realisability is not None:
            self.realisability.note(self._offer)
            self._plan_on_realisable()
        # a known placement that proved the learner wrong ends the chain as a query does; a
        # stack made where nothing can be placed on it tells where it stood, not where the
        # plan leads (the same plan in the same scene builds it elsewhere next time)
        self.outcomes.made(self._scene, step.state, step.action, known=not taught_it,
                           leads=not self._built_out_of_reach(step, execution))
        self.environment.mark_scene_changed(record.index)
        self.on_experiment(record, step)
        # A scene that offers nothing but the table (a stack whose top is beyond reach and
        # one loose block) cannot teach anything: have it reset, as a person would.
        self._table_only = self._table_only + 1 if execution.available == [0] else 0
        limit = self.policy.stuck_reset
        self.maybe_reset(force=bool(limit) and self._table_only >= limit,
                         why="only the table offered")
        return record

    def make_record(self, step: Step, execution: ExecutionRecord) -> ExperimentRecord:
        bank = self.explorer.bank
        return ExperimentRecord(
            index=len(self.log),
            state=int(step.state),
            action=int(step.action) + 1,
            label=int(step.label),
            mode=MODE_NAMES[step.mode],
            setting=int(execution.setting),
            available=[int(s) for s in execution.available],
            moved_block=execution.moved_block,
            attempts=int(execution.attempts),
            instance=execution.instance,
            margin_before=float(step.margin_before),
            confidence_before=float(step.chi_before),
            weights_before=[] if step.weights_before is None else
            [float(v) for v in step.weights_before],
            weights_after=[float(v) for v in bank.weights(step.state)],
            stage_s={k: round(float(v), 4) for k, v in execution.stage_s.items()},
            dropped_before=dict(sorted(self.dropped.items())),
            wall_time=float(self.wall_clock()),
            resets_before=self._resets_since_experiment,
            unknown_offered=self._unknown_offered,
            offer=[[int(h), int(a) + 1] for h, a in sorted(self._offer)],
        )

    def maybe_reset(self, force: bool = False, why: str = "repeated failures") -> None:
        away = self.environment.blocks_out_of_reach()
        if not away and not force:
            return
        self._table_only = 0
        reason = f"blocks out of reach: {', '.join(away)}" if away else why
        try:
            message = self.environment.reset()
            # the next observation must be of the new scene, not of whatever the memory had
            # folded in when the reset returned (that depended on thread timing)
            self.environment.mark_scene_changed()
            self.outcomes.restart()
            self.resets += 1
            self._resets_since_experiment += 1
            self.logger.info(f"reset the world ({reason}): {message}")
        except (TimeoutError, ExperimentAborted) as exc:
            self.logger.warning(f"could not reset the world ({reason}): {exc}")
