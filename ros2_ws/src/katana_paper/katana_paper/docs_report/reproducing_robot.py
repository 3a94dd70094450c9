"""The robot's sections of docs/REPRODUCING.md (section 3.3): the measured truth, the runs
against it with their claim verdicts, and the stacking skill; apart from the abstract world's
sections because they read other files (the truth, the runs, the skill trials)."""

from __future__ import annotations

from . import reproducing_text as prose
from .claims import RunSection, heights_of, pct, uncertain_pairs
from .formatting import NOT_RECORDED, Json, count_of, finite, get, num, strategies_of, table
from .provenance import made_by, not_measured, robot_paper_command, skill_command, truth_command


def _pairs(truth: Json, key: str) -> set[tuple[int, int]]:
    """The (height, action) pairs the truth lists under `key`."""
    return {(int(h), int(a)) for h, a in get(truth, key, default=[]) or []}


def truth_table(truth: Json) -> str:
    """P(stays) per height and action with its trials, or why a pair has none."""
    p = get(truth, "p_stable", default={}) or {}
    n_actions = max((int(a) for row in p.values() for a in row), default=0)
    impossible = _pairs(truth, "impossible")
    unrealised = _pairs(truth, "never_realised_by_the_fovea")

    def cell(h: str, a: int) -> str:
        if (int(h), a) in impossible:
            return "cannot occur"
        if (int(h), a) in unrealised:
            return "not realised"
        value = get(p, h, str(a))
        return f"{num(value, 2)} ({get(truth, 'trials', h, str(a))})" if finite(value) else \
            "not measured"

    rows = [(f"{h} (table)" if h == "0" else h, *(cell(h, a) for a in range(1, n_actions + 1)))
            for h in sorted(p, key=int)]
    return table(("height", *(f"a{a}" for a in range(1, n_actions + 1))), rows)


def parallax_actions(truth: Json, margin: float = 0.5) -> list[int]:
    """Actions that stay far more often on the highest stack than on every lower one above the
    table: the parallax of the paper's pixel intersection (see prose.TRUTH_PARALLAX)."""
    p = get(truth, "p_stable", default={}) or {}
    heights = sorted(int(h) for h in p if int(h) > 0)
    if len(heights) < 2:
        return []
    top, lower = heights[-1], heights[:-1]
    out = []
    for a in sorted({int(a) for a in p.get(str(top), {})}):
        high = get(p, str(top), str(a))
        lows = [get(p, str(h), str(a)) for h in lower]
        if finite(high) and lows and all(finite(v) and high - v > margin for v in lows):
            out.append(a)
    return out


def truth_section(truth: Json) -> str:
    """The measured truth: how it was measured, its table and its uncertain pairs."""
    if truth is None:
        return not_measured("robot-truth")
    m = get(truth, "measurement", default={}) or {}
    pairs = uncertain_pairs(truth)
    parts = [
        f"{made_by(truth_command(truth), truth)} {num(m.get('placements'))} pick-and-places "
        f"and {num(m.get('resets'))} resets"
        + (f" in {num(m['wall_s'] / 60, 0)} minutes" if finite(m.get("wall_s")) else "")
        + ". P(the placed block stays), with the trials in brackets (Wilson 95 % intervals in "
        "the file):", "",
        truth_table(truth), "",
        "Pairs whose outcome is uncertain (0.05 < P < 0.95): "
        + (", ".join(f"({h}, {a}) at {num(p, 2)}" for h, a, p in pairs) or "none") + "."]
    odd = parallax_actions(truth)
    if odd:
        parts += ["", prose.TRUTH_PARALLAX.format(actions=", ".join(f"a{a}" for a in odd))]
    return "\n".join(parts)


def robot_runs_table(data: Json) -> str:
    """Per strategy: final KL per height and overall, KL after 30, highest stack, waste."""
    strategies = strategies_of(data)
    heights = heights_of(strategies)
    rows = []
    for key, s in strategies.items():
        per_seed = ", ".join(str(v) for v in s.get("highest_stack_per_seed") or [])
        done = sum(s.get("experiments_done") or [])
        rows.append((
            key, *(num(get(s, "final_kl", h)) for h in heights),
            num(s.get("final_kl_overall")), num(s.get("kl_overall_after_30")),
            f"{s.get('highest_stack')} ({per_seed})",
            f"{s.get('wasted_experiments')} of {done} ({pct(s.get('wasted_share'), 1)} %)"
            if finite(s.get("wasted_share")) else NOT_RECORDED))
    return table(("strategy", *(f"KL h{h}" for h in heights), "overall", "overall after 30",
                  "highest stack (per seed)", "wasted"), rows)


def _robot_settings(data: Json) -> str:
    return (made_by(robot_paper_command(data), data)
            + f" Each run is {get(data, 'experiments')} experiments; seeds "
            f"{', '.join(str(s) for s in get(data, 'seeds', default=[]))}."
            + RERUN_NOTE)


#: what a rerun repeats (DESIGN.md: the orderings that keep the fast sim deterministic)
RERUN_NOTE = (" A rerun of the same seeds writes the same experiment logs (but for their wall "
              "times) on this machine, "
              "loaded or not (two runs of `make robot-paper` side by side were equal in all 8 "
              "runs; docs/DESIGN.md, after the fast sim's /clock). Not checked across CPUs, whose "
              "floating-point paths may differ.")


#: section 3.3's runs: their settings, the table and the verdicts on the paper's claims (from
#: their claims.json)
robot_section = RunSection("robot-paper", _robot_settings, prose.ROBOT_TABLE, robot_runs_table,
                           prose.ROBOT_CLAIMS)


#: the full study of `make robot-study`: seeds x strategies x experiments
FULL_STUDY = (20, 8, 120)


def _study_settings(data: Json) -> str:
    """The study's command, its runs and what an experiment costs, with the full study's
    projected wall time at the same cost."""
    costs = [s.get("s_per_experiment") for s in strategies_of(data).values()
             if finite(s.get("s_per_experiment"))]
    jobs = get(data, "jobs")
    if not costs or not finite(jobs) or not jobs:
        return _robot_settings(data)
    cost = sorted(costs)[len(costs) // 2]
    seeds, strategies, experiments = FULL_STUDY
    hours = seeds * strategies * experiments * cost / jobs / 3600
    return (_robot_settings(data)
            + f" An experiment took {num(cost, 2)} s in each run (the median over the runs), "
            f"with {jobs} runs at a time: the full study (`make robot-study`, {seeds} seeds x "
            f"{strategies} strategies x {experiments} experiments) takes about "
            f"{num(hours, 1)} hours on this machine, or a Ray cluster by "
            "`STUDY_ADDRESS=ray://HEAD:10001`.")


#: the study: section 3.3's runs at the scale the claims need (make robot-study)
study_section = RunSection("robot-study", _study_settings, prose.ROBOT_TABLE, robot_runs_table,
                           prose.STUDY_CLAIMS)


#: the seeds the study said would decide Q1 against Random after 30 experiments, run once
after30_section = RunSection("robot-after30", _robot_settings, prose.ROBOT_TABLE,
                             robot_runs_table, prose.AFTER30_CLAIMS)


def skill_section(data: Json) -> str:
    """The skill trials: stacks built, placements per success and falls of each model."""
    if data is None:
        return not_measured("robot-skill")
    rows = []
    for m in get(data, "models", default=[]) or []:
        pps = m.get("placements_per_success")
        rows.append((f"`{m.get('model')}`", count_of(m.get("success_rate"), m.get("trials")),
                     num(pps, 1) if pps is not None else "-", m.get("falls")))
    return "\n".join([
        made_by(skill_command(data), data)
        + f" Goal: a stack of {get(data, 'goal_height')} within "
        f"{get(data, 'max_placements')} placements, from the same scatters for every model; "
        "success is the simulator's ground truth, not the skill's own judge.", "",
        table(("model", "stacks built", "placements per success", "falls"), rows)])
