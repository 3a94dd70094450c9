"""The pick-and-place geometry the whole graph shares: one definition, one value.

pick_place_executor plans every pick and place with `approach_height` and `grasp_offset`, and
refuses a goal outside the reach they give (core.reach). fovea_node offers placements inside
that reach, and curiosity_node and skill_node choose the block to move by it. So every one of
these nodes declares the parameters below, read-only, and computes the reach with
`reach_geometry` from them: graph.yaml sets them once for all nodes, under `/**`, never under
one node (a test refuses a packaged file that does). A change needs a restart of the graph;
a live change in one node would make its plans and the others' offers disagree.

The defaults are the planner's (core.pick_place_types.PickPlaceParams); the other planner
settings the reach depends on are not parameters.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from katana_common.params import Param

from katana_manipulation.core.pick_place_types import PickPlaceParams, ReachGeometry

_DEFAULTS = PickPlaceParams()

REACH_PARAMS: tuple[Param, ...] = (
    Param("approach_height", _DEFAULTS.approach_height,
          "A descent onto a block or a place starts at most this far above the grasp or release "
          "point, m (read-only; set under /** for every node: the reach depends on it).",
          0.01, 0.2),
    Param("grasp_offset", _DEFAULTS.grasp_offset,
          "Tool point above the block centre when grasping, m (read-only; set under /** for "
          "every node: the reach depends on it).", -0.02, 0.02),
)


def planner_values(values: Mapping[str, Any]) -> dict[str, Any]:
    """The PickPlaceParams fields set by a node's REACH_PARAMS values."""
    return {p.name: values[p.name] for p in REACH_PARAMS}


def reach_geometry(values: Mapping[str, Any]) -> ReachGeometry:
    """The geometry the executor plans with, from a node's REACH_PARAMS values."""
    return PickPlaceParams(**planner_values(values)).geometry
