"""Which block to move for a placement (paper section 2.1), and which blocks the arm can pick."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class BlockView:
    """What the choice needs to know of a block (from memory/blocks)."""

    id: str
    x: float
    y: float
    on_top: bool
    level: int
    # known to stand upright; False: it fell onto its side (too tall and narrow to stack), or
    # it has not been seen clearly since it last moved, so that nobody knows
    upright: bool = True


@dataclass(frozen=True)
class PickReach:
    """Where the arm picks a block from above: radii from the pan axis, per block level.

    `bands_m[k]` is the (min, max) radius for a block at level k + 1; a level beyond the list,
    or an empty band (max <= min), cannot be picked. The figures come from the arm's
    kinematics (katana_manipulation.core.reach.pick_reach), not from a configuration.
    """

    bands_m: tuple[tuple[float, float], ...]

    def __post_init__(self) -> None:
        if not self.bands_m or not all(
            len(b) == 2 and all(math.isfinite(v) for v in b) for b in self.bands_m
        ):
            raise ValueError(f"reach: needs finite (min, max) radii per level, got {self.bands_m}")

    def can_pick(self, x: float, y: float, level: int) -> bool:
        if not 1 <= level <= len(self.bands_m):
            return False
        low, high = self.bands_m[level - 1]
        return low <= math.hypot(x, y) <= high

    def within_play_area(self, x: float, y: float) -> bool:
        """Where a block on the table can be picked (a top block elsewhere asks for a reset)."""
        return self.can_pick(x, y, 1)


def choose_block_to_move(
    blocks: Iterable[BlockView],
    placement_xy: tuple[float, float],
    target_stack: Sequence[str],
    reachable=lambda block: True,
    from_stacks_first: bool = False,
) -> BlockView | None:
    """The accessible upright top block furthest from the placement, never one of the target
    stack; with `from_stacks_first`, the top of the tallest stack before any loose block.

    Furthest first "avoids interference with the blocks at the selected placement location".
    Ties go to the lower block id, so the choice is deterministic. A block on its side stays
    where it lies: placed, it would stand on its side and measure the fall of a block the
    paper never stacks. A placement on the table starts a new stack: made with a loose block
    it leaves every stack as it was (on the sim the loop moved one block from the table to the
    table 83 times beside a three-stack it could not place on), made with a stack's top block
    it lowers that stack, which is what a plan back to the table is for.
    """
    excluded = set(target_stack)
    candidates = [b for b in blocks
                  if b.on_top and b.upright and b.id not in excluded and reachable(b)]
    if not candidates:
        return None
    px, py = placement_xy
    return max(candidates, key=lambda b: (b.level if from_stacks_first else 0,
                                          math.hypot(b.x - px, b.y - py), _neg(b.id)))


def movable_count(blocks: Iterable[BlockView], reachable=lambda block: True) -> int:
    """How many blocks the arm could move now: upright top blocks within reach (the same test
    as choose_block_to_move's, with no target stack)."""
    return sum(1 for b in blocks if b.on_top and b.upright and reachable(b))


def _neg(text: str) -> tuple[int, ...]:
    return tuple(-ord(c) for c in text)
