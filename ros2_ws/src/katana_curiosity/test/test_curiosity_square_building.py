"""square_building: a known placement on the way to a higher unknown pair is made with the
most overlap among the offered known actions about as stable as the plan's."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_curiosity.core.environment import Setting
from katana_curiosity.core.explorer import PLAN, Choice
from katana_curiosity.core.robot_loop import SQUARE_MARGIN_SLACK, robot_bank, square_building


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
