"""The parameters of curiosity_node, and the ones skill_node shares with it.

`ROBOT_PARAMS` is what both nodes declare, stated once: the robot's state-action space, the
plan's discount, the graph calls and their timeouts, and the scene and pick-and-place geometry
the reach is computed from. `PARAMS` is curiosity_node's whole spec; skill_node's is in
skill_node.py. `environment_config` turns either node's values into RobotEnvironment's
configuration, so both build it one way.

alpha, theta, gamma and strategy are applied live (`ros2 param set`, validated as at
start-up, shown in the next curiosity/learner_state); every other parameter is read-only.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from katana_common.params import Param
from katana_common.scene import SCENE_PARAMS
from katana_manipulation.core.pick_place_types import DEFAULT_GEOMETRY, ReachGeometry
from katana_manipulation.core.reach import pick_reach_table, place_reach_table
from katana_manipulation.reach_params import REACH_PARAMS, reach_geometry

from .core.block_choice import PickReach
from .core.predictors import ALPHA, GAMMA, THETA_ROBOT
from .core.strategies import STRATEGIES
from .robot_environment import EnvironmentConfig

ROBOT_PARAMS = (
    Param("max_height", 3, "Highest stack height placed upon (heights 0..max_height).", 0, 7),
    Param("n_actions", 6, "Actions per state: bits on + 1 (six on the robot).", 1, 32),
    Param("table_action", 1, "The only action on the table (no block in the fovea); 0: any.",
          0, 32),
    Param("gamma", GAMMA, "Discount factor of the plan (live: the next plan uses it).", 0.0,
          0.999, live=True),
    Param("grasp_retries", 2, "Retries of a missed grasp before the attempt is dropped.", 0, 10),
    Param("service_timeout_s", 10.0, "Timeout of each service call, s.", 0.1, 600.0),
    Param("action_timeout_s", 120.0, "Timeout of one pick-and-place, s.", 1.0, 3600.0),
    Param("blocks_timeout_s", 10.0, "Wait for a fresh memory/blocks, s.", 0.1, 600.0),
    Param("ready_timeout_s", 120.0, "Wait for the arm and the graph before the first "
          "placement, s.", 0.1, 3600.0),
    Param("reset_service", "", "ResetWorld service; '': the backend's (the one in the graph)."),
    *(p for p in SCENE_PARAMS if p.name in ("world_frame", "block_size")),
    *REACH_PARAMS,
)

PARAMS = (
    Param("strategy", "q1", "Exploration strategy (live).", choices=tuple(STRATEGIES), live=True),
    Param("alpha", ALPHA, "Query condition scale alpha, Eq. 2 (live).", 1e-3, 100.0, live=True),
    Param("theta", THETA_ROBOT, "Query threshold theta, Eq. 2; the robot's, paper section 3.3 "
          "(live).", 0.0, 1.0, live=True),
    Param("run_dir", "runs/robot", "Folder of experience.jsonl and learner.npz; resumes.",
          nonempty=True),
    Param("quarantine_bad_lines", False, "Move bad lines of the experience log to "
          "experience.jsonl.quarantine and resume (false: a bad line stops the start, named)."),
    Param("max_experiments", 0, "Stop after this many experiments in total (0: never).",
          0, 10_000_000),
    Param("seed", 0, "Seed of the strategy's random choices.", 0, 2**31 - 1),
    Param("stuck_reset", 3, "Reset after this many experiments in a row offering only the "
          "table (0: never).", 0, 1000),
    Param("setting_changes", 3, "Resets instead of a planned placement that is known and "
          "leads to no unknown pair, or that left the offer unchanged the last time, since the "
          "last experiment that taught the learner, before the plan is followed anyway "
          "(0: never).", 0, 1000),
    Param("stop_when_all_known", True, "End the run once no (height, action) pair the arm "
          "can realise is unknown (false: keep planning on the known model)."),
    Param("unrealisable_after", 30, "A pair never offered in this many logged settings that "
          "offer its height is one the arm does not realise: no phantom reward (0: never).",
          0, 100_000),
    *ROBOT_PARAMS,
)


def cross_check(v) -> str | None:
    if v["table_action"] > v["n_actions"]:
        return f"parameter 'table_action' is {v['table_action']}; valid: 0..{v['n_actions']}"
    return None


def pick_reach_of(max_height: int, block_height_m: float,
                  geometry: ReachGeometry = DEFAULT_GEOMETRY) -> PickReach:
    """Where a block can be picked at levels 1..max_height + 1: the arm's kinematics with the
    executor's pick-and-place geometry (katana_manipulation.core.reach)."""
    return PickReach(tuple((b.min_m, b.max_m) for b in pick_reach_table(
        max_height + 1, block_height_m, geometry=geometry)))


def place_reach_of(values: Mapping[str, Any]) -> tuple[tuple[float, float], ...]:
    """(near, far) radius of a placement on a stack of each height 0..max_height, m."""
    return tuple((b.min_m, b.max_m) for b in place_reach_table(
        values["max_height"], values["block_size"][2], geometry=reach_geometry(values)))


def environment_config(values: Mapping[str, Any]) -> EnvironmentConfig:
    """RobotEnvironment's configuration from a node's ROBOT_PARAMS values."""
    return EnvironmentConfig(
        n_actions=values["n_actions"], max_height=values["max_height"],
        grasp_retries=values["grasp_retries"],
        reach=pick_reach_of(values["max_height"], values["block_size"][2],
                            reach_geometry(values)),
        service_timeout_s=values["service_timeout_s"],
        action_timeout_s=values["action_timeout_s"],
        blocks_timeout_s=values["blocks_timeout_s"], reset_service=values["reset_service"],
        place_reach_m=place_reach_of(values))
