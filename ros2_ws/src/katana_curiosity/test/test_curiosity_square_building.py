"""How a known placement on the way to a higher unknown pair is made: square_building, with the
most overlap among the offered known actions about as stable as the plan's; build_turn, turned
against the block below when the stack it makes is to offer the action only turned faces
offer and that is the one pair left unknown there; every other placement square."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_curiosity.core.environment import Setting
from katana_curiosity.core.explorer import PLAN, Choice
from katana_curiosity.core.progress import unknown_realisable
from katana_curiosity.core.robot_loop import (
    BUILD_TURN_RAD,
    SQUARE_MARGIN_SLACK,
    TURNED_ACTION,
    build_turn,
    feasible_actions,
    robot_bank,
    square_building,
)

TURNED = TURNED_ACTION - 1  # 0-based


def _taught(labels: dict[tuple[int, int], list[int]]):
    bank = robot_bank(3, 6, 1.0, 0.1)
    for (h, a), seq in labels.items():
        for label in seq:
            bank.update(h, a, float(label))
    return bank


def test_a_building_placement_is_made_square_when_that_is_about_as_stable() -> None:
    # height 2: action 4 (index 3) always stable, action 6 (index 5) stable 9 times in 10
    bank = _taught({(2, 3): [1] * 20, (2, 5): [1] * 9 + [-1] + [1] * 10})
    assert not bank.unknown[2, 3] and not bank.unknown[2, 5]
    assert bank.margin[2, 5] < bank.margin[2, 3] < bank.margin[2, 5] + SQUARE_MARGIN_SLACK
    offer = Setting.from_pairs(np.array([2, 2, 2]), np.array([0, 3, 5]))
    made = square_building(bank, offer, Choice(2, 3, PLAN, 1))
    assert (made.state, made.action, made.mode) == (2, 5, PLAN)
    not_offered = Setting.from_pairs(np.array([2, 2]), np.array([0, 3]))
    assert square_building(bank, not_offered, Choice(2, 3, PLAN, 1)).action == 3


def test_a_query_and_a_much_less_stable_square_placement_are_left_as_chosen() -> None:
    bank = _taught({(2, 3): [1] * 20, (2, 5): [1, -1] * 10})
    offer = Setting.from_pairs(np.array([2, 2]), np.array([3, 5]))
    assert bank.margin[2, 5] < bank.margin[2, 3] - SQUARE_MARGIN_SLACK
    assert square_building(bank, offer, Choice(2, 3, PLAN, 0)).action == 3
    fresh = robot_bank(3, 6, 1.0, 0.1)  # everything unknown: the chosen pair is a query
    assert square_building(fresh, offer, Choice(2, 3, PLAN, 0)) == Choice(2, 3, PLAN, 0)


@settings(max_examples=200, deadline=None)
@given(labels=st.dictionaries(st.tuples(st.integers(1, 3), st.integers(0, 5)),
                              st.lists(st.sampled_from([-1, 1]), min_size=1, max_size=12),
                              max_size=12),
       offered=st.sets(st.tuples(st.integers(1, 3), st.integers(0, 5)), min_size=1),
       data=st.data())
def test_the_square_choice_is_the_highest_offered_known_action_above_the_floor(
        labels, offered, data) -> None:
    bank = _taught(labels)
    pairs = sorted(offered)
    setting = Setting.from_pairs(np.array([h for h, _ in pairs]), np.array([a for _, a in pairs]))
    state, action = data.draw(st.sampled_from(pairs))
    made = square_building(bank, setting, Choice(state, action, PLAN, 0))
    assert made.state == state and made.mode == PLAN
    if bank.unknown[state, action]:
        assert made.action == action
        return
    floor = max(bank.margin[state, action] - SQUARE_MARGIN_SLACK, 0.0)
    eligible = [a for h, a in pairs if h == state and not bank.unknown[h, a]
                and bank.margin[h, a] >= floor]
    assert made.action == max(eligible + [action])


def _everything_but(unknown_pairs: set[tuple[int, int]]):
    """A bank that knows every pair but those (each taught stable 20 times, the rest never)."""
    return _taught({(h, a): [1] * 20 for h in range(4) for a in range(6)
                    if (h, a) not in unknown_pairs})


def test_the_placement_that_makes_the_stack_where_only_action_5_is_unknown_is_turned() -> None:
    bank = _everything_but({(3, TURNED)})
    unknown = bank.unknown.copy()
    assert unknown[3, TURNED] and unknown.sum() == 1
    assert build_turn(bank, unknown, Choice(2, 5, PLAN, 0), 3) == BUILD_TURN_RAD
    # a placement further down the way (the two-stack) is square: only the last one turns
    assert build_turn(bank, unknown, Choice(1, 5, PLAN, 0), 3) == 0.0
    # on the table a new stack of one has one face: nothing to turn against
    assert build_turn(bank, unknown, Choice(0, 0, PLAN, 0), 1) == 0.0
    # no plan goal, or no table of realisable pairs (a strategy that does not plan)
    assert build_turn(bank, unknown, Choice(2, 5, PLAN, 0), None) == 0.0
    assert build_turn(bank, None, Choice(2, 5, PLAN, 0), 3) == 0.0


def test_a_query_and_a_goal_with_other_pairs_unknown_are_placed_square() -> None:
    bank = _everything_but({(3, 2), (2, 5)})
    unknown = bank.unknown.copy()
    assert build_turn(bank, unknown, Choice(2, 3, PLAN, 0), 3) == 0.0  # (3, 3) is unknown
    assert build_turn(bank, unknown, Choice(2, 5, PLAN, 0), 3) == 0.0  # a query: as offered
    both = _everything_but({(3, 2), (3, TURNED)})  # any three-stack offers (3, 3) to learn
    assert build_turn(both, both.unknown.copy(), Choice(2, 5, PLAN, 0), 3) == 0.0


@settings(max_examples=200, deadline=None)
@given(unknown_pairs=st.sets(st.tuples(st.integers(0, 3), st.integers(0, 5)), max_size=6),
       state=st.integers(0, 3), action=st.integers(0, 5), goal=st.none() | st.integers(0, 4))
def test_a_turn_is_given_exactly_to_known_last_placements_towards_unknown_action_5(
        unknown_pairs, state, action, goal) -> None:
    bank = _everything_but(unknown_pairs)
    realisable = unknown_realisable(bank, feasible_actions(3, 6, 1), 4)
    turn = build_turn(bank, realisable, Choice(state, action, PLAN, 0), goal)
    wanted = (goal is not None and state >= 1 and goal == state + 1 and goal <= 3
              and not bank.unknown[state, action] and realisable[goal, TURNED]
              and realisable[goal].sum() == 1)
    assert turn == (BUILD_TURN_RAD if wanted else 0.0)
