"""`katana-robot skill`: the arm and perception with skill_node, build_stack goals from the same
scattered settings, with the model a run learned and with an untrained one: skill.json."""

from __future__ import annotations

import json
from pathlib import Path

from katana_bringup.in_process import InProcessGraph
from katana_bringup.run import build_nodes, overrides_for
from katana_common.action_client import ActionClient
from katana_common.testing import wait_until
from katana_curiosity.skill_node import PARAMS as SKILL_NODE_PARAMS
from katana_curiosity.skill_node import SkillNode
from katana_interfaces.action import BuildStack
from rclpy.parameter import Parameter

from .graph_client import GraphClient, graph_params

#: how long a trial waits, after its result, for feedback still on its way (seconds)
FEEDBACK_WAIT_S = 5.0

#: what skill_node takes of the parameters the graph's YAML sets for it: the ones it declares
#: (its own and node_params.ROBOT_PARAMS: the scene, and the reach geometry under `/**` that
#: every node computes the reach from). Not the rest of `/**`: the camera's pose, and
#: use_sim_time (the node keeps its own clock; its waits for a fresh memory/blocks then go by
#: message count, not by stamp)
SKILL_PARAMETERS = frozenset(p.name for p in SKILL_NODE_PARAMS)


def _trial(g: InProcessGraph, client: GraphClient, action: ActionClient, seed: int,
           goal_height: int, max_placements: int) -> dict:
    """One build_stack goal from the scatter reset_world(seed) makes."""
    client.reset(seed)
    feedback: list = []
    handle = g.result(action.send_goal_async(
        BuildStack.Goal(target_height=goal_height, max_placements=max_placements),
        feedback_callback=lambda f, fb=feedback: fb.append(f.feedback)), 30.0)
    result = g.result(handle.get_result_async(), 60.0 * max_placements + 60.0).result
    # one feedback per placement, on a channel of its own: the last may come after the result
    wait_until(lambda: len(feedback) >= result.placements, FEEDBACK_WAIT_S)
    truth_height = max((b.level for b in client.settled(0.3)), default=0)
    return {
        "seed": seed, "success": bool(result.success), "reason": result.reason,
        "height_reached": int(result.height_reached), "truth_height": int(truth_height),
        "placements": int(result.placements), "falls": int(result.falls),
        "choices": [[int(f.state), int(f.action), round(float(f.predicted_success), 3),
                     int(f.observed_label)] for f in feedback]}


def skill_trials(model: str, goal_height: int, trials: int, seed: int, max_placements: int,
                 log=print) -> dict:
    """`trials` build_stack goals, each from the scatter reset_world(seed + k) makes."""
    params = graph_params(seed)
    params["skill_node"] = {"model": model}
    outcomes = []
    with InProcessGraph() as g:
        g.add(*build_nodes("sim", params, g.context, layers=("arm", "perception")))
        g.add(SkillNode(context=g.context, parameter_overrides=[
            p for p in overrides_for("skill_node", params) if p.name in SKILL_PARAMETERS]
            + [Parameter("max_placements", value=max_placements)]))
        node = g.node("skill_client")
        client = GraphClient(node)
        client.wait_ready()
        action = ActionClient(node, BuildStack, "build_stack")
        if not action.wait_for_server(timeout_sec=30.0):
            raise TimeoutError("build_stack is not available")
        for k in range(trials):
            o = _trial(g, client, action, seed + k, goal_height, max_placements)
            outcomes.append(o)
            log(f"katana-robot skill ({model or 'untrained'}): trial {k}: {o['reason']}, "
                f"height {o['height_reached']} (sim {o['truth_height']}), {o['placements']} "
                f"placements, {o['falls']} falls")
    wins = [o for o in outcomes if o["success"] and o["truth_height"] >= goal_height]
    return {"model": model or "untrained", "trials": trials, "goal_height": goal_height,
            "success_rate": len(wins) / trials if trials else None,
            "placements_per_success": (sum(o["placements"] for o in wins) / len(wins))
            if wins else None,
            "falls": sum(o["falls"] for o in outcomes), "outcomes": outcomes}


def cmd_skill(args) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    models = [str(args.model)] + ([] if args.no_untrained else [""])
    report = {"goal_height": args.goal_height, "trials": args.trials, "seed": args.seed,
              "max_placements": args.max_placements, "models": []}
    for model in models:
        report["models"].append(skill_trials(model, args.goal_height, args.trials, args.seed,
                                             args.max_placements))
        (out / "skill.json").write_text(json.dumps(report, indent=1) + "\n")
    print(f"{'model':<40} {'success':>8} {'placements/success':>19} {'falls':>6}")
    for m in report["models"]:
        pps = m["placements_per_success"]
        print(f"{m['model']:<40} {m['success_rate']:>8.2f} "
              f"{'-' if pps is None else f'{pps:.1f}':>19} {m['falls']:>6}")
    print(f"katana-robot skill: -> {out}/skill.json")
    return 0
