"""Which block is moved: against a brute-force reading of the paper's rule."""

import itertools
import math

from hypothesis import given
from hypothesis import strategies as st
from katana_curiosity.core.block_choice import (
    BlockView,
    PickReach,
    choose_block_to_move,
    movable_count,
)

REACH = PickReach(((0.12, 0.32), (0.13, 0.30), (0.15, 0.27)))

views = st.builds(
    BlockView,
    id=st.sampled_from(["red", "green", "blue", "yellow", "cyan", "orange"]),
    x=st.floats(0.0, 0.35), y=st.floats(-0.3, 0.3), on_top=st.booleans(),
    level=st.integers(1, 4), upright=st.booleans(),
)


@given(blocks=st.lists(views, max_size=6, unique_by=lambda b: b.id),
       target=st.lists(st.sampled_from(["red", "green", "blue"]), max_size=2, unique=True),
       px=st.floats(0.1, 0.3), py=st.floats(-0.15, 0.15))
def test_the_moved_block_is_the_furthest_accessible_upright_one(blocks, target, px, py):
    def reachable(b):
        return REACH.can_pick(b.x, b.y, b.level)

    got = choose_block_to_move(blocks, (px, py), target, reachable)
    eligible = [b for b in blocks
                if b.on_top and b.upright and b.id not in target and reachable(b)]
    if not eligible:
        assert got is None
        return
    assert got in eligible and got.upright  # one on its side is never moved
    far = max(math.hypot(b.x - px, b.y - py) for b in eligible)
    assert math.hypot(got.x - px, got.y - py) == far
    # ties go to the lowest id
    assert got.id == min(b.id for b in eligible if math.hypot(b.x - px, b.y - py) == far)


def test_a_block_on_its_side_is_left_even_when_it_is_the_furthest():
    near = BlockView("red", 0.2, 0.0, True, 1)
    lying = BlockView("blue", 0.2, 0.2, True, 1, upright=False)
    for order in itertools.permutations([near, lying]):
        assert choose_block_to_move(order, (0.2, -0.1), []) == near
    assert choose_block_to_move([lying], (0.2, -0.1), []) is None


@given(blocks=st.lists(views, max_size=6, unique_by=lambda b: b.id),
       px=st.floats(0.1, 0.3), py=st.floats(-0.15, 0.15))
def test_a_new_stack_is_started_with_the_top_of_the_tallest_stack(blocks, px, py):
    """For a placement on the table a stack's top comes before any loose block (moved from the
    table to the table it would change nothing); among equals, the furthest, then the id."""
    got = choose_block_to_move(blocks, (px, py), [], lambda b: True, from_stacks_first=True)
    eligible = [b for b in blocks if b.on_top and b.upright]
    if not eligible:
        assert got is None
        return
    tallest = max(b.level for b in eligible)
    assert got.level == tallest
    far = max(math.hypot(b.x - px, b.y - py) for b in eligible if b.level == tallest)
    assert math.hypot(got.x - px, got.y - py) == far


def test_the_livelock_scene_moves_the_three_stacks_top_not_the_loose_block():
    loose = BlockView("yellow", 0.25, 0.12, True, 1)
    top_of_three = BlockView("red", 0.20, -0.08, True, 3)
    under = [BlockView("green", 0.20, -0.08, False, 2), BlockView("blue", 0.20, -0.08, False, 1)]
    scene = [loose, top_of_three, *under]
    table_spot = (0.15, 0.0)
    assert choose_block_to_move(scene, table_spot, []) == loose  # furthest: the paper's rule
    assert choose_block_to_move(scene, table_spot, [], from_stacks_first=True) == top_of_three


@given(blocks=st.lists(views, max_size=6, unique_by=lambda b: b.id),
       px=st.floats(0.1, 0.3), py=st.floats(-0.15, 0.15))
def test_the_movable_blocks_are_those_the_choice_would_move_one_after_the_other(blocks, px, py):
    def reachable(b):
        return REACH.can_pick(b.x, b.y, b.level)

    moved: list[str] = []
    while (got := choose_block_to_move(blocks, (px, py), moved, reachable)) is not None:
        moved.append(got.id)
    assert movable_count(blocks, reachable) == len(moved)
