"""core.progress: futile plans, everything known, and the run's waste figures from the log."""

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from katana_curiosity.core.environment import Setting
from katana_curiosity.core.planner import Planner
from katana_curiosity.core.predictors import GAMMA, QueryRule
from katana_curiosity.core.progress import (
    FutilePlans,
    Realisability,
    last_query,
    longest_identical_plan_streak,
    offer_of,
    unknown_offered,
    unknown_realisable,
    wasted_experiments,
)
from katana_curiosity.core.robot_loop import feasible_actions, robot_bank
from katana_curiosity.core.run_record import ExperimentRecord

RULE = QueryRule(1.0, 0.1)
KNOWN = {"margin_before": 0.9, "confidence_before": 0.05}  # chi below theta and |margin|
UNKNOWN = {"margin_before": 0.0, "confidence_before": 0.5}


def record(index, mode="plan", state=0, action=2, available=(0, 3), resets_before=0,
           known=True):
    return ExperimentRecord(index=index, state=state, action=action, label=1, mode=mode,
                            available=list(available), resets_before=resets_before,
                            **(KNOWN if known else UNKNOWN))


def test_the_offer_is_the_set_of_distinct_pairs_in_the_setting():
    setting = Setting.from_pairs(np.array([0, 0, 3, 3, 0]), np.array([0, 0, 5, 4, 0]))
    assert offer_of(setting) == {(0, 0), (3, 5), (3, 4)}


def test_a_plan_is_futile_only_when_the_scene_after_it_is_the_same():
    plans = FutilePlans()
    before = frozenset({(0, 0), (3, 5)})
    plans.observed(before)
    plans.made(before, 0, 0)
    assert not plans.observed(frozenset({(0, 0), (1, 5), (3, 5)}))  # it changed the world
    assert not plans.is_futile(before, 0, 0)
    plans.restart()  # an experiment on an unknown pair: a new chain
    plans.observed(before)
    plans.made(before, 0, 0)
    assert plans.observed(before)
    assert plans.is_futile(before, 0, 0)
    assert not plans.is_futile(before, 3, 5)  # another pair in the same scene
    assert not plans.is_futile(frozenset({(0, 0)}), 0, 0)  # the same pair in another scene


def test_a_plan_that_closes_a_cycle_of_known_plans_is_futile():
    """Build a two-stack the arm cannot use (scene b), take it down again (back to a)."""
    plans = FutilePlans()
    a, b = frozenset({(0, 0), (1, 3)}), frozenset({(0, 0)})
    plans.observed(a)
    plans.made(a, 1, 3)
    assert not plans.observed(b)
    plans.made(b, 0, 0)
    assert plans.observed(a), "back in a scene of the chain"
    assert plans.is_futile(b, 0, 0) and not plans.is_futile(a, 1, 3)


def test_the_plan_into_a_dead_end_is_futile():
    plans = FutilePlans()
    a, b = frozenset({(0, 0), (1, 3)}), frozenset({(0, 0)})
    plans.observed(a)
    plans.made(a, 1, 3)
    plans.observed(b)
    plans.dead_end()  # in b the loop had to change the setting
    assert plans.is_futile(a, 1, 3)
    plans.dead_end()  # said once: nothing else led here
    assert plans.futile == {(a, 1, 3)}


def test_what_is_futile_is_forgotten_when_the_learner_learns():
    plans = FutilePlans()
    scene = frozenset({(0, 0)})
    plans.observed(scene)
    plans.made(scene, 0, 0)
    assert plans.observed(scene)
    plans.restart()  # a reset: still futile
    assert plans.is_futile(scene, 0, 0)
    plans.learned()  # an experiment on an unknown pair
    assert not plans.is_futile(scene, 0, 0)


def test_a_reset_between_plan_and_observation_proves_nothing():
    plans = FutilePlans()
    scene = frozenset({(0, 0)})
    plans.observed(scene)
    plans.made(scene, 0, 0)
    plans.restart()
    assert not plans.observed(scene)
    plans.dead_end()
    assert not plans.futile


def test_unknown_pairs_follow_the_query_condition():
    bank = robot_bank(max_height=2, n_actions=6, alpha=1.0, theta=0.1)
    feasible = feasible_actions(2, 6, table_action=1)
    assert unknown_realisable(bank, feasible, top=3).tolist() == feasible[:3].tolist()
    assert unknown_offered(bank, frozenset({(0, 0), (1, 5)})) == 2
    rng = np.random.default_rng(0)
    for _ in range(400):  # lots of consistent labels make every pair known
        for h in range(3):
            for a in range(6):
                bank.update(h, a, 1 if a >= 3 else -1 if rng.random() < 0.98 else 1)
    expected = [[bool(feasible[h, a] and bank.rule.is_query(bank.margin[h, a], bank.chi[h, a]))
                 for a in range(6)] for h in range(3)]
    assert unknown_realisable(bank, feasible, top=3).tolist() == expected
    assert unknown_offered(bank, frozenset({(0, 0), (1, 5)})) == int(
        bank.unknown[0, 0]) + int(bank.unknown[1, 5])


def test_the_livelock_of_83_table_placements_is_one_streak_and_all_wasted():
    records = [record(i, mode="query", state=1, known=False) for i in range(3)]
    records += [record(i) for i in range(3, 86)]
    assert longest_identical_plan_streak(records) == 83
    assert wasted_experiments(records, RULE) == list(range(3, 86))
    assert last_query(records) == 2


def test_plans_that_lead_to_a_query_are_not_wasted_and_a_reset_ends_a_chain():
    records = [
        record(0, state=0), record(1, state=1),  # build towards height 2 ...
        record(2, mode="query", state=2, known=False),  # ... and query there: useful
        record(3, state=0), record(4, state=0),  # two known placements, then a reset
        record(5, mode="query", state=0, known=False, resets_before=1),
    ]
    assert wasted_experiments(records, RULE) == [3, 4]
    assert longest_identical_plan_streak(records) == 2


@given(st.lists(st.tuples(st.sampled_from(["query", "plan", "random"]), st.integers(0, 2),
                          st.integers(1, 3), st.booleans(), st.integers(0, 1)), max_size=40))
def test_the_log_figures_against_a_brute_force_reading(rows):
    records = [record(i, mode=m, state=s, action=a, known=k, resets_before=r)
               for i, (m, s, a, k, r) in enumerate(rows)]
    # brute force: an experiment is useful if it was unknown, or a later unknown one follows it
    # with no reset on the way; the streak is the longest run of equal planned keys
    wasted = []
    for i, r in enumerate(records):
        if not r.confidence_before == KNOWN["confidence_before"]:
            continue
        useful = False
        for later in records[i + 1:]:
            if later.resets_before:
                break
            if later.confidence_before != KNOWN["confidence_before"]:
                useful = True
                break
        if not useful:
            wasted.append(i)
    assert wasted_experiments(records, RULE) == wasted
    best = 0
    for i in range(len(records)):
        j = i
        while (j < len(records) and records[j].mode == "plan"
               and (records[j].state, records[j].action) == (records[i].state, records[i].action)):
            j += 1
        best = max(best, j - i)
    assert longest_identical_plan_streak(records) == best
    queries = [r.index for r in records if r.mode == "query"]
    assert last_query(records) == (queries[-1] if queries else None)


def test_a_pair_never_offered_in_enough_settings_of_its_height_is_unrealisable():
    feasible = feasible_actions(3, 6, table_action=1)
    realisable = Realisability(feasible, evidence=3)
    on_two = frozenset({(0, 0), (2, 0), (2, 5)})
    for _ in range(2):
        realisable.note(on_two)
    assert realisable.table[2, 4], "two settings are not evidence enough"
    realisable.note(on_two)
    table = realisable.table
    assert not table[2, 4] and table[2, 0] and table[2, 5]
    assert table[3].tolist() == feasible[3].tolist(), "a height never offered keeps every pair"
    realisable.note(frozenset({(2, 4)}))
    assert realisable.table[2, 4], "offered once: realisable again"
    assert Realisability(feasible, evidence=0).table.tolist() == feasible.tolist()


def test_planning_on_a_new_feasible_table_equals_planning_on_it_from_the_start():
    bank = robot_bank(max_height=3, n_actions=6, alpha=1.0, theta=0.1)
    for _ in range(100):
        for h in range(4):
            for a in range(6):
                if (h, a) != (2, 4):
                    bank.update(h, a, 1 if a >= 2 else -1)
    feasible = feasible_actions(3, 6, table_action=1)
    assert np.argwhere(bank.unknown[:4] & feasible[:4]).tolist() == [[2, 4]]
    planner = Planner(bank, 4, GAMMA, feasible=feasible)
    before = planner.solve().copy()
    narrower = feasible.copy()
    narrower[2, 4] = False
    planner.set_feasible(narrower)
    after = planner.solve()
    fresh = Planner(bank, 4, GAMMA, feasible=narrower).solve()
    np.testing.assert_allclose(after, fresh, atol=1e-9)
    assert before[1].max() > 0.5 and after.max() == 0.0, "no phantom reward left at (2, 5)"
    planner.set_feasible(feasible)  # offered again: the reward comes back
    np.testing.assert_allclose(planner.solve(), before, atol=1e-9)
