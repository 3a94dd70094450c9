"""core.progress: where plans lead, everything known, and the run's waste figures from the log."""

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from katana_curiosity.core.environment import Setting
from katana_curiosity.core.planner import Planner
from katana_curiosity.core.predictors import GAMMA, QueryRule
from katana_curiosity.core.progress import (
    PlanOutcomes,
    Realisability,
    blocks_short,
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
           known=True, label=1):
    return ExperimentRecord(index=index, state=state, action=action, label=label, mode=mode,
                            available=list(available), resets_before=resets_before,
                            **(KNOWN if known else UNKNOWN))


def test_the_offer_is_the_set_of_distinct_pairs_in_the_setting():
    setting = Setting.from_pairs(np.array([0, 0, 3, 3, 0]), np.array([0, 0, 5, 4, 0]))
    assert offer_of(setting) == {(0, 0), (3, 5), (3, 4)}


NONE_UNKNOWN = np.zeros((4, 6), dtype=bool)


def unknown_at(*pairs):
    mask = NONE_UNKNOWN.copy()
    for h, a in pairs:
        mask[h, a] = True
    return mask


def walk(plans, *steps, known=True):
    """Scenes (name, offer) and the placements between them: (scene, (h, a), scene, ...)."""
    for i in range(0, len(steps) - 1, 2):
        (name, offer), (h, a) = steps[i], steps[i + 1]
        plans.observed(name, offer)
        plans.made(name, h, a, known)
    last = steps[-1]
    return plans.observed(*last)


def at(plans, scene):
    """After a reset, in `scene`: the chain is that scene alone."""
    plans.restart()
    plans.observed(*scene)


A = ("a", frozenset({(0, 0), (3, 5)}))
B = ("b", frozenset({(0, 0), (1, 3)}))
C = ("c", frozenset({(0, 0), (2, 4)}))
D = ("d", frozenset({(0, 0), (3, 1)}))


def test_a_plan_that_left_the_scene_as_it_was_leads_nowhere():
    plans = PlanOutcomes()
    assert walk(plans, A, (0, 0), A), "the placement changed nothing"
    assert plans.leads_nowhere("a", 0, 0, unknown_at((3, 5)))  # even though a offers unknown
    assert not plans.leads_nowhere("a", 3, 5, NONE_UNKNOWN), "never tried there: one try"
    assert not plans.leads_nowhere("b", 0, 0, NONE_UNKNOWN), "the same pair in another scene"


def test_a_plan_leads_somewhere_while_what_it_led_to_offers_an_unknown_pair():
    plans = PlanOutcomes()
    assert not walk(plans, A, (0, 0), B)
    at(plans, A)
    assert not plans.leads_nowhere("a", 0, 0, unknown_at((1, 3)))
    assert plans.leads_nowhere("a", 0, 0, unknown_at((2, 4))), "b offers only known pairs"
    # b -> c was made once: c's unknown pair is reachable from a through b
    walk(plans, B, (1, 3), C)
    at(plans, A)
    assert not plans.leads_nowhere("a", 0, 0, unknown_at((2, 4)))
    assert plans.leads_nowhere("a", 0, 0, NONE_UNKNOWN)


def test_a_placement_that_leads_nowhere_by_where_it_stood_is_no_outcome_of_the_plan():
    """A block placed where nothing can be placed on the stack it makes (out of reach) leads to
    a scene that offers only known pairs; made with leads=False, that outcome is not recorded:
    the plan gets its try in that scene again, while the scene still joins the chain."""
    plans = PlanOutcomes()
    plans.observed(*A)
    plans.made("a", 0, 0, leads=False)
    plans.observed(*B)
    assert plans.chain == ("a", "b") and not plans.tried("a", 0, 0)
    assert not plans.leads_nowhere("a", 0, 0, unknown_at((2, 4)))
    at(plans, A)
    walk(plans, A, (0, 0), B)  # the same outcome recorded: now it leads nowhere
    at(plans, A)
    assert plans.leads_nowhere("a", 0, 0, unknown_at((2, 4)))


def test_a_cycle_back_into_the_chain_is_no_way_forward():
    """Build a two-stack the arm cannot use (b), take it down again (back to a): in a, the
    plan into b is refused, since from b the only way on leads back into the chain."""
    plans = PlanOutcomes()
    walk(plans, A, (0, 0), B, (0, 0), A)
    assert plans.chain == ("a", "b", "a")
    assert plans.leads_nowhere("a", 0, 0, unknown_at((3, 5))), "a's own offer is no progress"
    at(plans, B)  # after a reset, in b: a is progress
    assert not plans.leads_nowhere("b", 0, 0, unknown_at((3, 5)))


def test_the_chain_ends_with_an_experiment_on_an_unknown_pair():
    plans = PlanOutcomes()
    walk(plans, A, (0, 0), B)
    plans.made("b", 1, 3, known=False)
    plans.observed(*C)
    assert plans.chain == ("c",)


def test_a_way_longer_than_the_deepest_plan_is_not_taken():
    plans = PlanOutcomes(depth=2)
    walk(plans, A, (0, 0), B, (1, 3), C, (2, 4), D)
    at(plans, A)
    assert not plans.leads_nowhere("a", 0, 0, unknown_at((2, 4))), "c: two placements on"
    assert plans.leads_nowhere("a", 0, 0, unknown_at((3, 1))), "d: three placements on"
    assert not PlanOutcomes(depth=3, _offers=plans._offers, _led_to=plans._led_to,
                            _tried=plans._tried).leads_nowhere("a", 0, 0, unknown_at((3, 1)))


def test_a_chain_of_as_many_known_placements_as_the_deepest_plan_goes_no_further():
    """Scenes a perceived detail tells apart (x1, x2, ...) hide a cycle from the graph; the
    count of known placements in the chain does not depend on how scenes are told apart."""
    plans = PlanOutcomes(depth=3)
    scenes = [(f"x{i}", frozenset({(0, 0)})) for i in range(4)]
    plans.observed(*scenes[0])
    for i in range(3):
        assert not plans.detour_too_long
        plans.made(scenes[i][0], 0, 0)
        plans.observed(*scenes[i + 1])
    assert plans.detour_too_long
    plans.made("x3", 1, 2, known=False)  # an experiment on an unknown pair ends the chain
    plans.observed(*scenes[0])
    assert not plans.detour_too_long and plans.chain == ("x0",)
    for _ in range(3):
        plans.made("x0", 0, 0)
        plans.observed(*scenes[0])
    assert plans.detour_too_long
    plans.restart()  # so does a reset
    assert not plans.detour_too_long


def test_a_reset_between_a_placement_and_the_next_scene_proves_nothing():
    plans = PlanOutcomes()
    plans.observed(*A)
    plans.made("a", 0, 0)
    plans.restart()
    assert not plans.observed(*A)
    assert not plans.tried("a", 0, 0) and not plans.leads_nowhere("a", 0, 0, NONE_UNKNOWN)


@given(st.lists(st.tuples(st.integers(0, 5), st.integers(0, 2), st.integers(0, 5)),
                min_size=1, max_size=30),
       st.lists(st.frozensets(st.tuples(st.integers(0, 3), st.integers(0, 5)), max_size=4),
                min_size=6, max_size=6),
       st.frozensets(st.tuples(st.integers(0, 3), st.integers(0, 5)), max_size=8),
       st.integers(0, 5), st.integers(0, 2), st.integers(1, 6))
def test_leads_nowhere_is_bounded_reachability_to_an_unknown_offer(edges, offers, unknown_pairs,
                                                                     start, action, depth):
    """Against an independent computation: layers of boolean matrix products over the scene
    graph, never into the starting scene."""
    plans = PlanOutcomes(depth=depth)
    for source, a, target in edges:
        plans.restart()
        plans.observed(source, offers[source])
        plans.made(source, 0, a)
        plans.observed(target, offers[target])
    at(plans, (start, offers[start]))
    unknown = unknown_at(*unknown_pairs)
    adjacency = np.zeros((6, 6), dtype=int)
    for source, _, target in edges:
        adjacency[source, target] = 1
    adjacency[:, start] = 0  # never into the starting scene
    layer = np.zeros(6, dtype=int)
    for s, a, t in edges:
        if s == start and a == action and t != start:
            layer[t] = 1
    reachable = layer.copy()
    for _ in range(depth - 1):
        layer = ((layer @ adjacency > 0) & (reachable == 0)).astype(int)
        reachable |= layer
    promising = any(unknown[h, a] for scene in np.flatnonzero(reachable)
                    for h, a in offers[scene])
    tried = any(s == start and a == action for s, a, _ in edges)
    assert plans.tried(start, 0, action) == tried
    assert plans.leads_nowhere(start, 0, action, unknown) == (tried and not promising)


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


def test_a_known_placement_the_learner_mispredicted_taught_it_and_ends_a_chain():
    """A placement known to stay that fell proved the learner wrong: its weights move on the
    mistake, so it and the known placements leading to it are not wasted; the known placement
    after it, ended by a reset, is."""
    records = [
        record(0, state=1), record(1, state=2, label=-1),  # known stable, fell
        record(2, state=0),
        record(3, mode="query", state=1, known=False, resets_before=1),
    ]
    assert wasted_experiments(records, RULE) == [2]


def _taught(r):
    """Independent reading: the pair was unknown (the test's UNKNOWN confidence) or the label
    differs from the sign of the margin the learner had."""
    unknown = r.confidence_before != KNOWN["confidence_before"]
    return unknown or np.sign(r.margin_before) != r.label


@given(st.lists(st.tuples(st.sampled_from(["query", "plan", "random"]), st.integers(0, 2),
                          st.integers(1, 3), st.booleans(), st.integers(0, 1),
                          st.sampled_from([1, 1, 1, -1])), max_size=40))
def test_the_log_figures_against_a_brute_force_reading(rows):
    records = [record(i, mode=m, state=s, action=a, known=k, resets_before=r, label=y)
               for i, (m, s, a, k, r, y) in enumerate(rows)]
    # brute force: an experiment is useful if it taught the learner, or a later one that did
    # follows it with no reset on the way; the streak is the longest run of equal planned keys
    wasted = []
    for i, r in enumerate(records):
        if _taught(r):
            continue
        useful = False
        for later in records[i + 1:]:
            if later.resets_before:
                break
            if _taught(later):
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


@given(st.integers(0, 5), st.integers(1, 7), st.integers(0, 8))
def test_blocks_short_against_building_the_stack_block_by_block(height, target, movable):
    """Build it: a pile of the movable blocks; on a stack, its old top is covered and the moved
    block tops it; on the table, the moved block is the base and the stack it came from
    uncovers one more block (at best); then every placement on the way to the query at
    `target`, the query included, takes another block off the pile."""
    pile = movable
    if height:
        pile -= 2  # the stack's old top, covered; the moved block, now its top
    else:
        pile -= 1  # the moved block, now the base ...
        pile += 1  # ... and the block its old stack uncovers
    placements = list(range(height + 1, target + 1))  # on heights height+1..target
    enough = True
    for _ in placements:
        if pile <= 0:
            enough = False
            break
        pile -= 1
    assert blocks_short(height, target, movable) == (not enough)
