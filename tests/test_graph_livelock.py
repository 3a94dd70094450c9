"""The livelock of long runs, built on the simulated arm: a stack of three whose top the arm can
pick, and one loose block. The fovea offers the table and a few placements on the stack's near
edge; the learner knows the table (stable) and height 3 (everything falls) and nothing between,
so the planner expects a placement on the table to lead to height 1 and plans it. Made, it
would move the loose block from the table to the table and leave the scene as it was (the
default demo once made it 83 times in a row). The loop sees that the only block it could move
lies on the table and changes the setting instead."""

from __future__ import annotations

import json

from katana_bringup.in_process import InProcessGraph
from katana_bringup.run import build_nodes
from katana_curiosity.core.run_record import LOG_NAME, ExperienceLog, ExperimentRecord
from katana_curiosity.curiosity_node import CuriosityNode
from katana_manipulation.core.reach import pick_reach, place_reach
from katana_paper.graph_client import GraphClient, graph_params, true_blocks
from katana_paper.truth import TruthMeasurer
from rclpy.parameter import Parameter

#: beyond the level-3 pick reach (0.208 m), within the place reach of heights 1 and 2, so the
#: stack can be built there and its top cannot be taken
OUT_OF_REACH_XY = (0.218, 0.0)
EXAMPLES_PER_PAIR = 20
#: the table stays; at height 3 every action falls; heights 1 and 2 are unknown
TAUGHT = [(0, 1, 1)] + [(3, a, -1) for a in range(1, 7)]
KNOWN = EXAMPLES_PER_PAIR * len(TAUGHT)


def _learner_that_knows_the_table_and_height_three(run_dir) -> None:
    log = ExperienceLog(run_dir / LOG_NAME)
    examples = [pair for pair in TAUGHT for _ in range(EXAMPLES_PER_PAIR)]
    for i, (state, action, label) in enumerate(examples):
        log.append(ExperimentRecord(index=i, state=state, action=action, label=label,
                                    mode="query"))


def test_a_table_placement_that_would_change_nothing_is_not_made(tmp_path):
    assert pick_reach(3, 0.03).max_m < OUT_OF_REACH_XY[0] < place_reach(2, 0.03).max_m
    _learner_that_knows_the_table_and_height_three(tmp_path)
    params = graph_params(seed=2)
    g = InProcessGraph()
    try:
        g.add(*build_nodes("sim", params, g.context, layers=("arm", "perception")))
        client = GraphClient(g.node("livelock_client"))
        client.wait_ready()
        TruthMeasurer(client, seed=2, max_height=3, block_height_m=0.03)._build(
            3, at_xy=OUT_OF_REACH_XY)
        assert sorted(b.level for b in true_blocks(client.latest_truth())) == [1, 1, 2, 3]
        learner = CuriosityNode(context=g.context, parameter_overrides=[
            Parameter("run_dir", value=str(tmp_path)),
            Parameter("max_experiments", value=KNOWN + 2),
            Parameter("use_sim_time", value=True)])
        g.add(learner)
        g.wait_for(learner.finished.is_set, timeout=240.0)
    finally:
        g.close()
    records = [json.loads(line) for line in (tmp_path / LOG_NAME).read_text().splitlines()]
    first, second = records[KNOWN:]
    assert first["dropped_before"].get("table_to_table") == 1, first
    assert first["resets_before"] >= 1
    assert ("plan", 0) not in {(r["mode"], r["state"]) for r in (first, second)}
