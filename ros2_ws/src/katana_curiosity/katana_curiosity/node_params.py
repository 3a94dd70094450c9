"""The curiosity node's parameters: names, defaults, valid values, and which apply live.

alpha, theta, gamma and strategy are applied live (`ros2 param set`, validated as at
start-up, shown in the next curiosity/learner_state); every other parameter is read-only.
"""

from __future__ import annotations

from katana_common.params import Param
from katana_common.scene import SCENE_PARAMS

from .core.explorer import STRATEGIES

PARAMS = (
    Param("strategy", "q1", "Exploration strategy (live).", choices=tuple(STRATEGIES), live=True),
    Param("alpha", 1.0, "Query condition scale alpha, Eq. 2 (live).", 1e-3, 100.0, live=True),
    Param("theta", 0.1, "Query threshold theta, Eq. 2; 0.1 on the robot (live).", 0.0, 1.0,
          live=True),
    Param("gamma", 0.95, "Discount factor of the planner (live).", 0.0, 0.999, live=True),
    Param("max_height", 3, "Highest stack height placed upon (heights 0..max_height).", 0, 7),
    Param("n_actions", 6, "Actions per state: bits on + 1 (six on the robot).", 1, 32),
    Param("table_action", 1, "The only action on the table (no block in the fovea); 0: any.",
          0, 32),
    Param("run_dir", "runs/robot", "Folder of experience.jsonl and learner.npz; resumes.",
          nonempty=True),
    Param("max_experiments", 0, "Stop after this many experiments in total (0: never).",
          0, 10_000_000),
    Param("seed", 0, "Seed of the strategy's random choices.", 0, 2**31 - 1),
    Param("grasp_retries", 2, "Retries of a missed grasp before the attempt is dropped.", 0, 10),
    Param("service_timeout_s", 10.0, "Timeout of each service call, s.", 0.1, 600.0),
    Param("action_timeout_s", 120.0, "Timeout of one pick-and-place, s.", 1.0, 3600.0),
    Param("blocks_timeout_s", 10.0, "Wait for a fresh memory/blocks, s.", 0.1, 600.0),
    Param("ready_timeout_s", 120.0, "Wait for the arm and the graph before the first "
          "experiment, s.", 0.1, 3600.0),
    Param("reset_service", "", "ResetWorld service; '': the backend's (the one in the graph)."),
    Param("stuck_reset", 3, "Reset after this many experiments in a row offering only the "
          "table (0: never).", 0, 1000),
    Param("setting_changes", 3, "Resets in a row instead of a planned placement that is known "
          "and leads to no unknown pair, before the plan is followed anyway (0: never).",
          0, 1000),
    *(p for p in SCENE_PARAMS if p.name in ("world_frame", "block_size")),
)
LIVE = ("alpha", "theta", "gamma", "strategy")


def cross_check(v) -> str | None:
    if v["table_action"] > v["n_actions"]:
        return f"parameter 'table_action' is {v['table_action']}; valid: 0..{v['n_actions']}"
    return None
