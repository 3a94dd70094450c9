"""core.robot_loop without ROS: the drop, retry and reset policy, stopping, determinism."""

import random
import threading
from dataclasses import replace

import numpy as np
import pytest
from katana_curiosity.core.environment import Outcome, Setting
from katana_curiosity.core.explorer import PLAN, QUERY, Choice, Explorer, Step
from katana_curiosity.core.predictors import GAMMA
from katana_curiosity.core.robot_loop import (
    GIVE_UP,
    RETRY_SAME,
    TRY_ANOTHER,
    UNREALISABLE,
    ExecutionRecord,
    ExperimentAborted,
    LoopPolicy,
    RobotLoop,
    Stopping,
    Unrealisable,
    after_failed_pick_place,
    feasible_actions,
    leads_towards_unknown,
    leave_until_moved,
    robot_bank,
    set_query_rule,
)
from katana_curiosity.core.run_record import ExperienceLog, InstanceRecord, replay
from katana_curiosity.core.strategies import STRATEGIES, make_strategy


class Logger:
    def __init__(self) -> None:
        self.lines: list[str] = []

    def info(self, text: str) -> None:
        self.lines.append(text)

    warning = error = info


class ScriptedArm:
    """A RobotEnvironment whose failures follow a script and whose labels a seeded model."""

    def __init__(self, seed: int, failures: dict[int, Exception] | None = None,
                 away_after: int | None = None, table_only: bool = False) -> None:
        self.rng = random.Random(seed)
        self.failures = failures or {}
        self.attempt = 0
        self.resets = 0
        self.away_after = away_after
        self.table_only = table_only
        self.stop_on_attempt: tuple[int, threading.Event] | None = None
        self.calls: list[str] = []

    def wait_until_current(self) -> None:
        self.calls.append("wait")

    def mark_scene_changed(self, experience: int | None = None) -> None:
        self.calls.append("mark")

    def observe(self) -> Setting:
        self.calls.append("observe")
        self.attempt += 1
        if self.stop_on_attempt and self.attempt == self.stop_on_attempt[0]:
            self.stop_on_attempt[1].set()
            raise Stopping("stopped")
        failure = self.failures.get(self.attempt)
        if failure is not None:
            raise failure
        states = [0] if self.table_only else [0, 0, 1, 1, 2]
        return Setting.from_pairs(np.array(states), np.array([0, 1, 2, 3, 4][:len(states)]))

    def execute(self, state: int, action: int, index: int | None = None) -> Outcome:
        label = 1 if self.rng.random() < (1.0 if state == 0 else (action + 1) / 7) else -1
        available = [0] if self.table_only else [0, 1, 2]
        inst = InstanceRecord(1.0, 2.0, [False] * 5, [0.0] * 7, [], [0.2, 0.0, 0.015])
        return Outcome(label, ExecutionRecord(inst, self.attempt, available, "b1", 1,
                                              {"pick_place_s": 0.1}))

    def blocks_out_of_reach(self) -> list[str]:
        return ["b3"] if self.away_after is not None and self.attempt >= self.away_after else []

    def reset(self) -> str:
        self.calls.append("reset")
        self.resets += 1
        self.away_after = None
        return "scattered"


def make_loop(tmp_path, arm, max_experiments=10, seed=0, clock=None, stuck_reset=3,
              setting_changes=3, strategy="q1"):
    bank = robot_bank(3, 6, 1.0, 0.1)
    strategy = make_strategy(strategy, bank, 4, GAMMA, seed=seed,
                             feasible=feasible_actions(3, 6, 1))
    explorer = Explorer(arm, bank, strategy, record_weights=True)
    published = []
    loop = RobotLoop(arm, explorer, ExperienceLog(tmp_path / "experience.jsonl"),
                     LoopPolicy(max_experiments=max_experiments, stuck_reset=stuck_reset,
                                backoff_s=0.0, setting_changes=setting_changes),
                     lambda record, step: published.append(record), Logger(),
                     wall_clock=clock or (lambda: 5.0))
    return loop, published


@pytest.mark.parametrize("name", sorted(STRATEGIES))
def test_every_strategy_runs_on_the_robot_loop(tmp_path, name) -> None:
    """Each strategy of the registry (the paper's and the baselines) drives the robot loop:
    its choices are pairs the setting offered, and each is logged under its mode."""
    arm = ScriptedArm(3)
    loop, published = make_loop(tmp_path, arm, max_experiments=12, strategy=name)
    assert loop.run() == "done: 12 experiments"
    offered = {(0, 1), (0, 2), (1, 3), (1, 4), (2, 5)}  # ScriptedArm's setting, 1-based actions
    assert {(r.state, r.action) for r in loop.log.records} <= offered
    assert published == loop.log.records
    assert {r.mode for r in loop.log.records} <= {"query", "plan", "random"}


def test_drops_are_counted_by_reason_in_the_next_record(tmp_path) -> None:
    failures = {2: Unrealisable("no_block_to_move", "none"),
                3: ExperimentAborted("block_slipped", "slipped"),
                4: TimeoutError("late"), 6: ExperimentAborted("block_slipped", "slipped")}
    loop, published = make_loop(tmp_path, ScriptedArm(0, failures), max_experiments=4)
    assert loop.run().startswith("done")
    assert [r.dropped_before for r in loop.log.records] == [
        {}, {"block_slipped": 1, "no_block_to_move": 1, "timeout": 1},
        {"block_slipped": 1}, {}]
    assert published == loop.log.records
    assert loop.dropped_total == {"block_slipped": 2, "no_block_to_move": 1, "timeout": 1}
    assert loop.environment.resets == 1, "three drops in a row reset the world"


def test_a_block_out_of_reach_or_a_table_only_scene_asks_for_a_reset(tmp_path) -> None:
    arm = ScriptedArm(0, away_after=3)
    loop, _ = make_loop(tmp_path / "a", arm, max_experiments=5)
    loop.run()
    assert arm.resets == 1
    arm = ScriptedArm(0, table_only=True)
    # (no setting changes for plans that change nothing: this checks the stuck_reset count)
    loop, _ = make_loop(tmp_path / "b", arm, max_experiments=7, stuck_reset=3,
                        setting_changes=0)
    loop.run()
    assert arm.resets == 2, "after experiments 3 and 6, each offering only the table"
    # every reset is marked, so the next observation waits for a picture of the new scene
    # (without the mark it took whatever the memory had folded in: thread timing)
    calls = " ".join(arm.calls)
    assert calls.count("reset") == 2 and calls.count("reset mark wait observe") == 2, calls


def test_the_log_replays_to_the_learner_and_resumes(tmp_path) -> None:
    loop, _ = make_loop(tmp_path, ScriptedArm(1), max_experiments=6)
    loop.run()
    bank = robot_bank(3, 6, 1.0, 0.1)
    replay(bank, ExperienceLog(tmp_path / "experience.jsonl").records)
    np.testing.assert_array_equal(bank.w, loop.explorer.bank.w)
    assert [r.index for r in loop.log.records] == list(range(6))
    assert loop.run().startswith("done"), "nothing more to do at max_experiments"


def test_stop_ends_the_loop_at_once_with_the_log_intact(tmp_path) -> None:
    arm = ScriptedArm(0)
    loop, _ = make_loop(tmp_path, arm, max_experiments=100)
    arm.stop_on_attempt = (4, loop.stop)
    assert loop.run() == "stopped"
    assert len(ExperienceLog(tmp_path / "experience.jsonl")) == 3


def test_the_same_seed_gives_the_same_log_whatever_the_clock(tmp_path) -> None:
    ticks = iter(range(10_000))
    runs = []
    for name, clock in (("a", lambda: 1.0), ("b", lambda: float(next(ticks)) * 7.3)):
        failures = {3: ExperimentAborted("grasp_missed", "missed")}
        loop, _ = make_loop(tmp_path / name, ScriptedArm(11, failures), max_experiments=12,
                            seed=4, clock=clock)
        loop.run()
        runs.append([{k: v for k, v in r.__dict__.items() if k not in ("wall_time", "stage_s")}
                     for r in loop.log.records])
    assert runs[0] == runs[1]
    loop, _ = make_loop(tmp_path / "c", ScriptedArm(12), max_experiments=12, seed=4)
    loop.run()
    assert [r.label for r in loop.log.records] != [r["label"] for r in runs[0]]


def test_a_live_query_rule_change_recomputes_the_flags_not_the_weights() -> None:
    bank = robot_bank(3, 6, 1.0, 0.1)
    for i in range(30):
        bank.update(1, i % 6, 1.0 if i % 2 else -1.0)
    w = bank.w.copy()
    set_query_rule(bank, 50.0, 0.0)
    np.testing.assert_array_equal(bank.w, w)
    fresh = robot_bank(3, 6, 50.0, 0.0)
    for i in range(30):
        fresh.update(1, i % 6, 1.0 if i % 2 else -1.0)
    np.testing.assert_allclose(bank.chi, fresh.chi)
    np.testing.assert_array_equal(bank.unknown, fresh.unknown)


def test_the_retry_policy_after_a_failed_pick_and_place() -> None:
    table = {  # (result, goals sent so far) -> action, with 2 retries (3 goals at most)
        ("grasp_missed", 1): RETRY_SAME, ("grasp_missed", 2): RETRY_SAME,
        ("grasp_missed", 3): GIVE_UP, ("pick_unreachable", 1): TRY_ANOTHER,
        ("pick_unreachable", 3): GIVE_UP, ("place_unreachable", 1): UNREALISABLE,
        ("place_unreachable", 9): UNREALISABLE, ("block_slipped", 1): GIVE_UP,
        ("arm_did_not_reach", 1): GIVE_UP, ("timeout", 1): GIVE_UP,
    }
    for (result, attempts), action in table.items():
        assert after_failed_pick_place(result, attempts, 2) == action, (result, attempts)


class SettingUntilReset:
    """Offers `before` until the first reset, then `after`; a placement stays as `stays` says."""

    def __init__(self, before, after, stays, loose_blocks_only: bool = False) -> None:
        self.before, self.after, self.stays = before, after, stays
        self.loose_blocks_only = loose_blocks_only  # a table placement moves a loose block
        self.resets = 0

    def moves_a_loose_block(self, choice: Choice) -> bool:
        return self.loose_blocks_only and choice.state == 0

    def wait_until_current(self) -> None:
        pass

    def mark_scene_changed(self, experience: int | None = None) -> None:
        pass

    def observe(self) -> Setting:
        states, actions = zip(*(self.after if self.resets else self.before), strict=True)
        return Setting.from_pairs(np.array(states), np.array(actions))

    def execute(self, state: int, action: int, index: int | None = None) -> Outcome:
        inst = InstanceRecord(1.0, 2.0, [False] * 5, [0.0] * 7, [], [0.2, 0.0, 0.015])
        label = 1 if self.stays(state, action) else -1
        return Outcome(label, ExecutionRecord(inst, self.resets, [0, 1], "b1", 1, {}))

    def blocks_out_of_reach(self) -> list[str]:
        return []

    def reset(self) -> str:
        self.resets += 1
        return "scattered"


def _known_up_to_height_one(arm, tmp_path, setting_changes=3, stays_on_one=(5,)):
    """A loop whose learner knows heights 0 and 1 (on 1, the actions `stays_on_one` stay, action
    6 by default, the others fall) and nothing of height 2: a planned placement is worth making
    only if it can grow a two-stack."""
    loop, _ = make_loop(tmp_path, arm, max_experiments=1)
    loop.policy = LoopPolicy(max_experiments=1, backoff_s=0.0, setting_changes=setting_changes)
    bank = loop.explorer.bank
    for _ in range(40):
        bank.update(0, 0, 1)
        for a in range(6):
            bank.update(1, a, 1 if a in stays_on_one else -1)
    feasible = feasible_actions(3, 6, 1)
    assert not (bank.unknown[:2] & feasible[:2]).any() and bank.unknown[2].all()
    return loop


def test_a_known_plan_leading_nowhere_changes_the_setting_instead(tmp_path) -> None:
    """No experiment wasted: the setting of loose blocks offers on height 1 only action 1, which
    the learner knows falls (and the table, where a loose block would only move). The loop
    resets instead of making either; the new setting offers action 6, which stays and grows the
    two-stack whose pairs are unknown, and that experiment is made."""
    arm = SettingUntilReset([(0, 0), (1, 0)], [(0, 0), (1, 0), (1, 5)],
                            stays=lambda s, a: s == 0 or a == 5, loose_blocks_only=True)
    loop = _known_up_to_height_one(arm, tmp_path)
    loop.explorer.strategy.planner.solve()
    strategy = loop.explorer.strategy
    q = strategy.planner.q
    assert q[2].max() > 0.5 and q[1, 5] > q[1, 0], "the plan values growing the two-stack"
    assert not leads_towards_unknown(strategy, Choice(1, 0, PLAN, 1))
    assert leads_towards_unknown(strategy, Choice(1, 5, PLAN, 2))
    assert loop.run().startswith("done")
    [record] = loop.log.records
    assert arm.resets == 1 and (record.state, record.action, record.label) == (1, 6, 1)
    assert record.mode == "plan" and record.dropped_before == {"no_route_to_unknown": 1}


def test_a_setting_no_reset_improves_is_used_after_the_allowed_changes(tmp_path) -> None:
    arm = SettingUntilReset([(0, 0), (1, 0)], [(0, 0), (1, 0)], stays=lambda s, a: s == 0,
                            loose_blocks_only=True)
    loop = _known_up_to_height_one(arm, tmp_path, setting_changes=2)
    assert loop.run().startswith("done")
    [record] = loop.log.records
    assert arm.resets == 2 and (record.state, record.action) == (1, 1)
    assert record.dropped_before == {"no_route_to_unknown": 2}


def test_with_nothing_unknown_anywhere_every_plan_is_worth_making(tmp_path) -> None:
    loop, _ = make_loop(tmp_path, ScriptedArm(0), max_experiments=1)
    bank, strategy = loop.explorer.bank, loop.explorer.strategy
    for _ in range(40):
        for s in range(4):
            for a in range(6):
                bank.update(s, a, -1)
    assert not (bank.unknown[:4] & feasible_actions(3, 6, 1)[:4]).any()
    strategy.planner.solve()
    assert leads_towards_unknown(strategy, Choice(1, 0, PLAN, 0))


def test_the_feasibility_table_leaves_out_what_the_fovea_cannot_offer() -> None:
    """On the table only action 1; on one block not action 5 (the perception tests check the
    fovea agrees); on stacks every action (action 5 does occur on turned top faces)."""
    feasible = feasible_actions(3, 6, 1)
    assert feasible.shape == (5, 6)
    assert feasible[0].tolist() == [True, False, False, False, False, False]
    assert feasible[1].tolist() == [True, True, True, True, False, True]
    assert feasible[2:].all()
    assert feasible_actions(3, 4, 1)[1].all()  # another fovea: no such geometry assumed


def test_blocks_the_arm_cannot_take_are_left_until_they_move() -> None:
    for name in ("grasp_missed", "block_slipped", "pick_unreachable"):
        action = after_failed_pick_place(name, attempts=3, retries=2)  # retries used up
        assert leave_until_moved(name, action), name
    assert not leave_until_moved("grasp_missed", after_failed_pick_place("grasp_missed", 1, 2))
    for name in ("place_unreachable", "arm_did_not_reach", "collision"):  # not the block's fault
        assert not leave_until_moved(name, after_failed_pick_place(name, 1, 2)), name


def test_a_setting_with_no_usable_instance_is_reset_at_once(tmp_path) -> None:
    """Nothing moved, so observing it again would offer nothing again: one drop, one reset
    (a transient failure, a slip, is retried up to failures_before_reset times first)."""
    failures = {2: Unrealisable("no_usable_instance", "none"),
                4: ExperimentAborted("block_slipped", "slipped")}
    arm = ScriptedArm(0, failures)
    loop, _ = make_loop(tmp_path, arm, max_experiments=3)
    assert loop.run().startswith("done")
    assert arm.resets == 1
    assert " ".join(arm.calls).count("observe reset") == 1  # right after the unusable setting
    assert loop.dropped_total == {"no_usable_instance": 1, "block_slipped": 1}


def _known_on_the_table_and_at_three(arm, tmp_path, max_experiments):
    """The livelock's learner: the table (action 1) and every pair at height 3 known, heights
    1 and 2 unknown; the scene offers the table and a three-stack (available [0, 3])."""
    loop, _ = make_loop(tmp_path, arm, max_experiments=max_experiments)
    loop.policy = LoopPolicy(max_experiments=max_experiments, backoff_s=0.0)
    bank = loop.explorer.bank
    for _ in range(40):
        bank.update(0, 0, 1)
        for a in range(6):
            bank.update(3, a, 1 if a == 5 else -1)
    assert not bank.unknown[0, 0] and not bank.unknown[3].any() and bank.unknown[1:3].all()
    return loop


def test_a_known_plan_that_left_the_offer_unchanged_is_not_made_again(tmp_path) -> None:
    """The livelock of the default demo: a three-stack the arm cannot place on and one loose
    block. Placing the block on the table again leaves the offer as it was; the planner, which
    expects height 1 next, plans it again. The loop makes it once, then changes the setting."""
    table_and_three = [(0, 0), (3, 0), (3, 5)]
    arm = SettingUntilReset(table_and_three, [(0, 0), (1, 0), (1, 5)], stays=lambda s, a: True)
    loop = _known_on_the_table_and_at_three(arm, tmp_path, max_experiments=2)
    assert loop.run().startswith("done")
    first, second = loop.log.records
    assert (first.mode, first.state, first.action) == ("plan", 0, 1)
    assert first.unknown_offered == 0 and first.resets_before == 0
    assert arm.resets == 1, "the same plan in the same offer was refused once"
    assert second.dropped_before == {"plan_leads_nowhere": 1} and second.resets_before == 1
    assert (second.mode, second.state) == ("query", 1) and second.unknown_offered == 2
    assert loop.outcomes.tried((frozenset({0, 3}), ()), 0, 0)  # heights offered, stacks


class CountingPlacements(SettingUntilReset):
    """The table and a three-stack; every placement stays and is counted in `made`."""

    def __init__(self) -> None:
        super().__init__([(0, 0), (3, 0)], [], stays=lambda s, a: True)
        self.made = 0

    def execute(self, state, action, index=None):
        self.made += 1
        return super().execute(state, action, index)


def test_a_plan_that_changed_only_the_actions_offered_left_the_scene_as_it_was(tmp_path) -> None:
    """Scenes are told apart by the heights offered and the stacks: the actions offered on a
    stack vary with where its top came to rest, and a cycle through such variants went on for
    25 experiments on the sim. A placement that only changed them changed nothing."""

    class MoreActions(CountingPlacements):
        def observe(self) -> Setting:
            if self.resets:
                offer = [(0, 0), (1, 0), (1, 5)]
            else:
                offer = [(0, 0), (3, 0), (3, 5), (3, 2)][: 2 + self.made]
            states, actions = zip(*offer, strict=True)
            return Setting.from_pairs(np.array(states), np.array(actions))

    arm = MoreActions()
    loop = _known_on_the_table_and_at_three(arm, tmp_path, max_experiments=2)
    assert loop.run().startswith("done")
    assert [(r.mode, r.state) for r in loop.log.records] == [("plan", 0), ("query", 1)]
    assert loop.log.records[1].dropped_before == {"plan_leads_nowhere": 1}


def test_when_everything_that_can_occur_is_known_the_loop_says_so_and_ends(tmp_path) -> None:
    loop, _ = make_loop(tmp_path, ScriptedArm(0), max_experiments=5)
    bank = loop.explorer.bank
    for _ in range(60):
        for s in range(4):
            for a in range(6):
                bank.update(s, a, 1 if a == 5 else -1)
    assert not (bank.unknown[:4] & feasible_actions(3, 6, 1)[:4]).any()
    assert loop.run() == "done: everything the arm can realise is known after 0 experiments"
    assert loop.all_known_at == 0 and len(loop.log) == 0
    assert any("is known after 0 experiments" in line for line in loop.logger.lines)
    # by the parameter, the loop goes on planning (the model keeps being refined, as the
    # paper's agent does once everything is known): it follows the plan, since no setting
    # has anything unknown to offer, and never resets for one
    loop.policy = LoopPolicy(max_experiments=5, backoff_s=0.0, stop_when_all_known=False)
    assert loop.run() == "done: 5 experiments"
    assert {r.mode for r in loop.log.records} == {"plan"} and loop.all_known_at == 0
    assert loop.resets == 0 and not any(r.dropped_before for r in loop.log.records)


def test_the_same_offer_over_other_stacks_is_another_setting(tmp_path) -> None:
    """A plan that left the offer as it was but changed the stacks (a stack's top moved to the
    table) did change the scene: it is made again (a return to an earlier scene would not be:
    that closes a cycle)."""

    class StacksChange(CountingPlacements):
        def stack_heights(self) -> tuple[int, ...]:
            return ((1, 3), (1, 1, 2), (1, 1, 1, 1))[self.made]

    arm = StacksChange()
    loop = _known_on_the_table_and_at_three(arm, tmp_path, max_experiments=3)
    assert loop.run().startswith("done")
    assert [(r.mode, r.state) for r in loop.log.records] == [("plan", 0)] * 3
    assert arm.resets == 0


def test_a_table_placement_that_would_move_a_loose_block_changes_the_setting(tmp_path) -> None:
    """Only a loose block could be moved: placed on the table it leaves every stack as it was,
    so the loop changes the setting before making it."""

    class OnlyLooseBlocks(SettingUntilReset):
        def moves_a_loose_block(self, choice: Choice) -> bool:
            return choice.state == 0 and not self.resets

    arm = OnlyLooseBlocks([(0, 0), (3, 0), (3, 5)], [(0, 0), (1, 0), (1, 5)],
                          stays=lambda s, a: True)
    loop = _known_on_the_table_and_at_three(arm, tmp_path, max_experiments=1)
    assert loop.run().startswith("done")
    [record] = loop.log.records
    assert record.dropped_before == {"table_to_table": 1} and record.resets_before == 1
    assert (record.mode, record.state) == ("query", 1)


def test_known_plans_that_go_round_in_a_cycle_are_stopped(tmp_path) -> None:
    """Build a two-stack the arm cannot use, take it down again, build it again (seen on the
    sim for 100 experiments): once the cycle closes, its plans are refused and the setting
    changes."""

    class Cycle(CountingPlacements):
        def observe(self) -> Setting:
            offer = [(0, 0), (1, 0), (1, 5)] if self.resets else [(0, 0), (3, 0)]
            states, actions = zip(*offer, strict=True)
            return Setting.from_pairs(np.array(states), np.array(actions))

        def stack_heights(self) -> tuple[int, ...]:
            return (1, 3) if self.made % 2 == 0 else (2, 2)  # a, b, a, ...

    arm = Cycle()
    loop = _known_on_the_table_and_at_three(arm, tmp_path, max_experiments=3)
    assert loop.run().startswith("done")
    # a -> b, b -> a closes the cycle: back in a, the plan into b leads only back to a
    assert [(r.mode, r.state) for r in loop.log.records] == [("plan", 0)] * 2 + [("query", 1)]
    assert arm.resets == 1 and loop.log.records[2].dropped_before == {"plan_leads_nowhere": 1}


def test_known_plans_in_scenes_that_never_repeat_end_at_the_depth_of_the_deepest_plan(
        tmp_path) -> None:
    """Scenes told apart by a detail (here other stacks after every placement) hide any cycle
    from the graph of outcomes; after as many known plans as the deepest plan (4 for heights
    0-3) the setting changes all the same."""

    class NeverTheSame(CountingPlacements):
        def observe(self) -> Setting:
            offer = [(0, 0), (1, 0), (1, 5)] if self.resets else [(0, 0), (3, 0)]
            states, actions = zip(*offer, strict=True)
            return Setting.from_pairs(np.array(states), np.array(actions))

        def stack_heights(self) -> tuple[int, ...]:
            return (1,) * self.made + (3,)  # other stacks after every placement

    arm = NeverTheSame()
    loop = _known_on_the_table_and_at_three(arm, tmp_path, max_experiments=5)
    assert loop.run().startswith("done")
    assert [(r.mode, r.state) for r in loop.log.records] == [("plan", 0)] * 4 + [("query", 1)]
    assert arm.resets == 1 and loop.log.records[4].dropped_before == {"detour_too_long": 1}


def test_a_refused_plan_gives_way_to_the_best_plan_worth_making(tmp_path) -> None:
    """The planner's first choice led back into its chain before; the setting also offers
    another placement on height 1 known to stay (action 4): that one is made, no reset."""
    arm = SettingUntilReset([(0, 0), (1, 0), (1, 3), (1, 5)], [],
                            stays=lambda s, a: s == 0 or a in (3, 5))
    loop = _known_up_to_height_one(arm, tmp_path, stays_on_one=(3, 5))
    strategy = loop.explorer.strategy
    strategy.planner.solve()
    first = strategy.planned(arm.observe())
    scene, offer = (frozenset({0, 1}), ()), frozenset({(0, 0), (1, 0), (1, 3), (1, 5)})
    loop.outcomes.observed(scene, offer)
    loop.outcomes.made(scene, first.state, first.action)
    loop.outcomes.observed(scene, offer)  # it changed nothing
    assert loop.run().startswith("done")
    [record] = loop.log.records
    assert arm.resets == 0 and record.mode == "plan" and record.dropped_before == {}
    assert record.state == 1 and (record.state, record.action - 1) != (first.state, first.action)


def test_a_known_build_that_leaves_no_block_to_put_on_the_stack_changes_the_setting(
        tmp_path) -> None:
    """Height 2 is unknown; the setting offers action 6 on a loose block (known to stay), but
    the arm can move only two blocks (the others fell onto their sides): the two-stack it would
    build has nothing left to be placed on it. The loop changes the setting instead; in the new
    one three blocks can be moved and the same placement is made."""

    class FewBlocks(SettingUntilReset):
        def movable_blocks(self) -> int:
            return 3 if self.resets else 2

    arm = FewBlocks([(0, 0), (1, 0), (1, 5)], [(0, 0), (1, 0), (1, 5)],
                    stays=lambda s, a: s == 0 or a == 5, loose_blocks_only=True)
    loop = _known_up_to_height_one(arm, tmp_path)
    assert loop.run().startswith("done")
    [record] = loop.log.records
    assert arm.resets == 1 and record.dropped_before == {"too_few_blocks": 1}
    assert (record.mode, record.state, record.action) == ("plan", 1, 6)


def test_a_known_placement_that_proved_the_learner_wrong_starts_a_new_chain(tmp_path) -> None:
    """Four known plans in scenes that never repeat are the deepest detour; when the fourth
    falls where the learner predicted it stays, the learner was taught and the chain starts
    again instead."""

    class FourthFalls(CountingPlacements):
        def execute(self, state, action, index=None):
            outcome = super().execute(state, action, index)
            return replace(outcome, label=-1) if self.made == 4 else outcome

        def stack_heights(self) -> tuple[int, ...]:
            return (1,) * self.made + (3,)

    arm = FourthFalls()
    loop = _known_on_the_table_and_at_three(arm, tmp_path, max_experiments=4)
    assert loop.run().startswith("done")
    records = loop.log.records
    assert [(r.mode, r.state) for r in records] == [("plan", 0)] * 4
    assert records[-1].label == -1 and records[-1].margin_before > 0
    assert not loop.outcomes.detour_too_long


def test_a_known_table_placement_beside_a_stack_of_one_changes_the_setting(tmp_path) -> None:
    """The setting offers a loose block to build on, but only with action 1, known to fall;
    the other plan, a table placement, would take a stack's top down for a base that is
    already there (`table_beside_a_base`). The loop changes the setting instead of making it
    and builds on the new one's base."""
    arm = SettingUntilReset([(0, 0), (1, 0)], [(0, 0), (1, 0), (1, 5)],
                            stays=lambda s, a: s == 0 or a == 5)
    loop = _known_up_to_height_one(arm, tmp_path)
    loop.explorer.strategy.planner.solve()
    assert leads_towards_unknown(loop.explorer.strategy, Choice(0, 0, PLAN, 0))
    assert loop.run().startswith("done")
    [record] = loop.log.records
    assert arm.resets == 1 and record.dropped_before == {"no_route_to_unknown": 1}
    assert (record.mode, record.state, record.action) == ("plan", 1, 6)


def test_a_known_placement_making_a_stack_out_of_reach_of_its_goal_changes_the_setting(
        tmp_path) -> None:
    """The loose block that action 6 would build on lies where a block cannot be placed on a
    two-stack (on the sim, a three-stack built there offered nothing at height 3, and the same
    plan in that scene was then refused as leading nowhere, in a scene where it would have led
    on). The plan is refused for its reach (`goal_out_of_reach`), the setting changes, and the
    same plan is made on the next setting's block, which is within reach."""

    class FarBase(SettingUntilReset):
        asked: list[tuple[int, int, int]] = []

        def out_of_reach_for(self, choice: Choice, target_height: int) -> bool:
            self.asked.append((choice.state, choice.action, target_height))
            return choice.state == 1 and not self.resets

    arm = FarBase([(0, 0), (1, 5)], [(0, 0), (1, 5)], stays=lambda s, a: s == 0 or a == 5)
    loop = _known_up_to_height_one(arm, tmp_path)
    assert loop.run().startswith("done")
    [record] = loop.log.records
    assert arm.resets == 1 and record.dropped_before == {"goal_out_of_reach": 1}
    assert (record.mode, record.state, record.action) == ("plan", 1, 6)
    assert (1, 5, 2) in arm.asked  # asked about the plan's goal: the unknown height 2


def test_a_stable_placement_out_of_reach_of_its_own_height_records_no_outcome(tmp_path) -> None:
    """After a placement, the loop asks the environment whether the stack it made stands where
    nothing can be placed on it (`out_of_reach_for` the stack's own height, on the instance
    made); such an outcome says where the block stood, not where the plan leads, and is not
    recorded (`PlanOutcomes.made(..., leads=False)`). A fall, or an instance found rather than
    offered, is recorded as ever."""

    class Reach(SettingUntilReset):
        asked: list[tuple[Choice, int]] = []

        def out_of_reach_for(self, choice: Choice, target_height: int) -> bool:
            self.asked.append((choice, target_height))
            return True

    arm = Reach([(0, 0)], [(0, 0)], stays=lambda s, a: True)
    loop = _known_up_to_height_one(arm, tmp_path)
    inst = InstanceRecord(1.0, 2.0, [False] * 5, [0.0] * 7, [], [0.2, 0.0, 0.015])
    step = Step(1, 4, QUERY, 1, 0.0, 0.0)
    assert loop._built_out_of_reach(step, ExecutionRecord(inst, 0, [0, 1], "b1", 1, index=3))
    assert arm.asked == [(Choice(1, 4, QUERY, 3), 2)]
    assert not loop._built_out_of_reach(replace(step, label=-1),
                                        ExecutionRecord(inst, 0, [0, 1], "b1", 1, index=3))
    assert not loop._built_out_of_reach(step, ExecutionRecord(inst, 0, [0, 1], "b1", 1))
    assert len(arm.asked) == 1


def test_a_known_table_placement_with_too_few_blocks_for_the_way_up_changes_the_setting(
        tmp_path) -> None:
    """Only the table is offered and the arm can move one block (a two-stack's top; the others
    lie on their sides): taking it down makes a base with nothing to build it up to height 2.
    The loop changes the setting instead of making the placement."""

    class OneBlock(SettingUntilReset):
        def movable_blocks(self) -> int:
            return 3 if self.resets else 1

    arm = OneBlock([(0, 0)], [(0, 0), (1, 0), (1, 5)], stays=lambda s, a: s == 0 or a == 5)
    loop = _known_up_to_height_one(arm, tmp_path)
    assert loop.run().startswith("done")
    [record] = loop.log.records
    assert arm.resets == 1 and record.dropped_before == {"too_few_blocks": 1}
    assert (record.mode, record.state, record.action) == ("plan", 1, 6)


def test_the_same_offer_and_stacks_with_more_movable_blocks_is_another_setting(tmp_path) -> None:
    """Where a plan leads depends on the blocks the arm can move (one on its side never is):
    on the sim, a three-stack built beside a fallen block offered nothing to query at height
    3, and the same plan after a reset, with every block upright, was refused for it. A scene
    with another count of movable blocks is another scene."""

    class MoreMovable(CountingPlacements):
        def movable_blocks(self) -> int:
            return 2 + self.made

    arm = MoreMovable()
    loop = _known_on_the_table_and_at_three(arm, tmp_path, max_experiments=3)
    assert loop.run().startswith("done")
    assert [(r.mode, r.state) for r in loop.log.records] == [("plan", 0)] * 3
    assert arm.resets == 0


class ScatterThenBase:
    """After a reset: loose blocks, a new scene each time, offering the table and action 6 on a
    block (known to stay, and it grows a two-stack). After that placement: a two-stack whose top
    offers only action 1, known to fall, so no plan there leads on (and nothing else is
    offered). A placement there leaves loose blocks again."""

    def __init__(self) -> None:
        self.resets = 0
        self.on_base = False

    def wait_until_current(self) -> None:
        pass

    def mark_scene_changed(self, experience: int | None = None) -> None:
        pass

    def stack_heights(self) -> tuple[int, ...]:
        return (1, 2) if self.on_base else (1,) * (2 + self.resets)  # a new scene per scatter

    def observe(self) -> Setting:
        pairs = [(2, 0)] if self.on_base else [(0, 0), (1, 5)]
        states, actions = zip(*pairs, strict=True)
        return Setting.from_pairs(np.array(states), np.array(actions))

    def execute(self, state: int, action: int, index: int | None = None) -> Outcome:
        inst = InstanceRecord(1.0, 2.0, [False] * 5, [0.0] * 7, [], [0.2, 0.0, 0.015])
        stays = state == 0 or action == 5
        self.on_base = state == 1 and stays
        return Outcome(1 if stays else -1, ExecutionRecord(inst, self.resets, [0, 1], "b1", 1,
                                                           {}))

    def blocks_out_of_reach(self) -> list[str]:
        return []

    def reset(self) -> str:
        self.resets += 1
        self.on_base = False
        return "scattered"


def test_a_cycle_of_a_known_placement_and_a_setting_change_reaches_the_bound(tmp_path) -> None:
    """Each scatter offers a base that leads on (known, so nothing is learned), and the stack of
    two it makes offers only a plan that leads nowhere. The setting changes are counted from
    the last experiment that taught the learner, not from the last one made: after three of
    them the plan on the stack of two is followed, where counting from the last experiment
    would build a base and scatter again for ever."""
    arm = ScatterThenBase()
    loop, _ = make_loop(tmp_path, arm, max_experiments=5)
    bank = loop.explorer.bank
    for _ in range(40):
        bank.update(0, 0, 1)
        for a in range(6):
            bank.update(1, a, 1 if a == 5 else -1)
            bank.update(2, a, -1 if a == 0 else 1)
    feasible = feasible_actions(3, 6, 1)
    assert not (bank.unknown[:3] & feasible[:3]).any() and bank.unknown[3].all()
    assert loop.run().startswith("done")
    made = [(r.state, r.action) for r in loop.log.records]
    assert made == [(1, 6)] * 4 + [(2, 1)], made
    assert arm.resets == 3
    assert [r.dropped_before for r in loop.log.records] == [
        {}, *[{"no_route_to_unknown": 1}] * 3, {}]
