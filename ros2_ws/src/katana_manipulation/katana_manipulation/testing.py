"""For tests of the reach: where the executor's planner can pick and place, found without
core.reach, so that a reach a node offers can be checked against the planner independently."""

from __future__ import annotations

import math

import numpy as np
from katana_description import models as m

from katana_manipulation.core.pick_place import (
    PickPlaceParams,
    PickPlacePlanner,
    PickPlaceRequest,
    PlanError,
)


class KinematicsOnly(PickPlacePlanner):
    """The planner without its reach check: only its inverse kinematics refuse a goal."""

    def check_target(self, xyz, size, what) -> None:
        pass


def plans(planner: PickPlacePlanner, pick_r: float, pick_level: int, place_r: float,
          place_height: int, pan: float = 0.3,
          block_size: tuple[float, float, float] = m.BLOCK_SIZE) -> tuple[bool, str]:
    """Whether `planner` plans a pick at `pick_r` from the pan axis (a block at `pick_level`,
    1: on the table) and a place at `place_r` on a stack of `place_height`: (ok, reason)."""
    h = block_size[2]
    req = PickPlaceRequest(
        pick=(pick_r * math.cos(pan), pick_r * math.sin(pan), (pick_level - 0.5) * h),
        pick_yaw=0.0, block_size=block_size,
        place=(place_r * math.cos(-pan), place_r * math.sin(-pan), (place_height + 0.5) * h),
        place_yaw=0.0)
    try:
        planner.plan(req, np.asarray(m.PARK_POSE, float))
    except PlanError as exc:
        return False, str(exc)
    return True, ""


def edge(works, inside: float, outside: float) -> float:
    """The radius where `works(r)` stops holding, between `inside` (works) and `outside`
    (does not; nearer the pan axis or farther from it), by bisection to 0.5 mm."""
    while abs(outside - inside) > 5e-4:
        mid = 0.5 * (inside + outside)
        inside, outside = (mid, outside) if works(mid) else (inside, mid)
    return inside


def place_limit_m(params: PickPlaceParams, height: int, inside: float,
                  outside: float = 0.6) -> float:
    """Where the planner's kinematics stop allowing a place on a stack of `height` (a pick
    from the table at 0.2 m), going from `inside` towards `outside`."""
    planner = KinematicsOnly(params=params)
    return edge(lambda r: plans(planner, 0.2, 1, r, height)[0], inside, outside)


def pick_limit_m(params: PickPlaceParams, level: int, inside: float,
                 outside: float = 0.6) -> float:
    """Where the planner's kinematics stop allowing a pick at `level` (a place on the table at
    0.2 m), going from `inside` towards `outside`."""
    planner = KinematicsOnly(params=params)
    return edge(lambda r: plans(planner, r, level, 0.2, 0)[0], inside, outside)
