"""The premise of the loop's turned building (katana_curiosity.core.robot_loop.build_turn),
checked on the fovea itself (katana_perception): a stack of three whose top block is placed
turned by BUILD_TURN_RAD against the one below offers the action only turned faces offer, and
every action the same stack built square offers; built square, as the arm leaves it, it
offers that action only now and then. Cross-package, so it lives here."""

from __future__ import annotations

import numpy as np
from katana_curiosity.core.robot_loop import BUILD_TURN_RAD, TURNED_ACTION
from katana_perception.core.calibration import Calibration
from katana_perception.core.fovea import FoveaScene
from katana_perception.core.memory import Block

CALIB = Calibration.overhead_default()
NAMES = ("red", "green", "blue")


def _offer_on_three(x: float, y: float, yaw: float, shifts, turns, top_turn: float) -> set[int]:
    """Actions offered on a stack of three built at (x, y, yaw), each block shifted and turned
    by the arm's placement error, the top one turned by `top_turn` more."""
    blocks, below = [], None
    for level, name in enumerate(NAMES, start=1):
        if level > 1:
            x, y = x + shifts[level - 2][0], y + shifts[level - 2][1]
            yaw += turns[level - 2] + (top_turn if level == 3 else 0.0)
        blocks.append(Block(name, name, x, y, yaw, support=below, level=level))
        below = name
    return {i.action for i in FoveaScene(blocks, CALIB).observe() if i.state == 3}


def test_a_three_stack_with_its_top_turned_offers_every_action_the_square_one_does_and_5():
    rng = np.random.default_rng(11)
    square_with_5 = 0
    for _ in range(30):
        x, y, yaw = rng.uniform(0.18, 0.24), rng.uniform(-0.1, 0.1), rng.uniform(-0.7, 0.7)
        shifts = rng.normal(0.0, 0.002, (2, 2))  # the arm's placement error, m and rad
        turns = rng.normal(0.0, 0.01, 2)
        square = _offer_on_three(x, y, yaw, shifts, turns, 0.0)
        turned = _offer_on_three(x, y, yaw, shifts, turns, BUILD_TURN_RAD)
        assert TURNED_ACTION in turned and square <= turned, (square, turned)
        square_with_5 += TURNED_ACTION in square
    assert square_with_5 < 25  # without the turn it hangs on the placement error
