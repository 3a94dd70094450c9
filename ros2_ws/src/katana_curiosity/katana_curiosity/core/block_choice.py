"""Which block to move for a placement (paper section 2.1)."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class BlockView:
    """What the choice needs to know of a block (from world/blocks)."""

    id: str
    x: float
    y: float
    on_top: bool
    level: int


def choose_block_to_move(
    blocks: Iterable[BlockView],
    placement_xy: tuple[float, float],
    target_stack: Sequence[str],
    reachable=lambda block: True,
) -> BlockView | None:
    """The accessible top block furthest from the placement, never one of the target stack.

    Furthest first "avoids interference with the blocks at the selected placement location".
    Ties go to the lower block id, so the choice is deterministic.
    """
    excluded = set(target_stack)
    candidates = [b for b in blocks if b.on_top and b.id not in excluded and reachable(b)]
    if not candidates:
        return None
    px, py = placement_xy
    return max(candidates, key=lambda b: (math.hypot(b.x - px, b.y - py), _neg(b.id)))


def _neg(text: str) -> tuple[int, ...]:
    return tuple(-ord(c) for c in text)
