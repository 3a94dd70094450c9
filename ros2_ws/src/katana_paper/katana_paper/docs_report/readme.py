"""README.md's results block: the headline figures, one row each, spliced between the
README's markers so that the rest of the README stays hand-written."""

from __future__ import annotations

from collections.abc import Mapping

from .claims import claims_counts
from .formatting import count_of, display, get, num, ratio, strategies_of, table
from .provenance import cpu_text
from .sources import README_BEGIN, README_END, README_MD

# The benches' headline rows, each a figure beside its floor or baseline from the same run:
# (bench, what, the figure's keys, the floor's keys, the floor's words, decimals, ratio decimals).
BENCH_ROWS = (
    ("core", "Q1 steps per second, compiled path", ("steps_per_s", "q1"),
     ("reference_steps_per_s", "q1"), "the NumPy reference in the same run", 3, 1),
    ("loop", "Seconds per experiment, the whole node graph on the fast sim",
     ("s_per_experiment",), ("experiment_floor_s",), "its floor in the same run", 2, 2),
    ("arm", "Seconds per pick-and-place through ROS on the fast sim", ("pick_place_s",),
     ("physics_only_s",), "physics alone in the same run", 3, 2),
    ("loop_hardware", "Seconds per experiment, the whole node graph on the Katana emulator in "
     "real time (40 ms per request, as the arm answers)", ("s_per_experiment",), ("motion_s",),
     "the arm's motion in the same run", 2, 2),
)


def readme_rows(results: Mapping) -> list[tuple[str, str, str]]:
    """The headline rows: the paper's two experiments, the skill and the benches' speeds."""
    rows = []
    paper = results.get("paper")
    rows.append((
        "Section 3.2, simulated blocks world: final KL to the true model, mean of the heights "
        "(lower is better)",
        ", ".join(f"{display(k)} {num(s.get('final_kl_overall'), 4)}"
                  for k, s in strategies_of(paper).items()) if paper else "not measured",
        f"`make paper`, {cpu_text(paper)}" if paper else "`make paper`"))
    robot = results.get("robot-paper")
    rows.append((
        "Section 3.3 on the simulated arm: final KL to the measured truth"
        + (f" after {get(robot, 'experiments')} experiments, mean of "
           f"{len(get(robot, 'seeds', default=[]))} seeds" if robot else ""),
        ", ".join(f"{k} {num(s.get('final_kl_overall'))}"
                  for k, s in strategies_of(robot).items()) if robot else "not measured",
        f"`make robot-paper`, {cpu_text(robot)}" if robot else "`make robot-paper`"))
    rows += claim_rows(results)
    skill = results.get("robot-skill")
    if skill is not None:
        cells = [("untrained" if m.get("model") == "untrained" else "learned")
                 + f" {count_of(m.get('success_rate'), m.get('trials'))}"
                 for m in get(skill, "models", default=[]) or []]
        rows.append((f"Stacking skill (Figure 14): stacks of {get(skill, 'goal_height')} built",
                     ", ".join(cells), f"`katana-robot skill`, {cpu_text(skill)}"))
    for name, what, key, floor_key, against, digits, ratio_digits in BENCH_ROWS:
        data = results.get(name)
        if data is not None:
            value, floor = get(data, *key), get(data, *floor_key)
            rows.append((what, f"{num(value, digits)}; {against} {num(floor, digits)} "
                         f"(ratio {ratio(value, floor, ratio_digits)})",
                         f"`python bench/run.py {name}`, {cpu_text(data)}"))
    return rows


# The claims.json files behind the README's claim rows: (result name, section, run folder).
CLAIM_ROWS = (("paper-claims", "3.2", "runs/paper"),
              ("robot-paper-claims", "3.3", "runs/robot-paper"),
              ("robot-study-claims", "3.3 at the study's scale", "runs/robot-study"),
              ("robot-after30-claims", "3.3 in the first 30 experiments", "runs/robot-after30"))


def claim_rows(results: Mapping) -> list[tuple[str, str, str]]:
    """One row per committed claims.json: the verdicts' counts (the claims and their intervals
    are in docs/REPRODUCING.md). No row where the file is missing."""
    rows = []
    for name, section, _ in CLAIM_ROWS:
        claims = results.get(name)
        if claims is not None:
            seeds = sorted({len(v) for v in (get(claims, "seeds", default={}) or {}).values()})
            rows.append((
                f"The paper's claims of section {section}, 95 % bootstrap intervals over "
                f"{'/'.join(map(str, seeds)) or 'no'} seeds per strategy "
                "([REPRODUCING.md](docs/REPRODUCING.md))",
                claims_counts(claims), f"`{get(claims, 'command')}`"))
    return rows


def render_readme_block(results: Mapping) -> str:
    """The results table between README.md's markers, the markers included."""
    return "\n".join([README_BEGIN,
                      table(("result", "measured", "command, CPU"), readme_rows(results)),
                      README_END])


def splice_readme(text: str, block: str) -> str:
    """README text with everything from the begin marker to the end marker replaced by
    `block`."""
    start, end = text.find(README_BEGIN), text.find(README_END)
    if start < 0 or end < start:
        raise ValueError(f"{README_MD} has no results block ({README_BEGIN} ... {README_END})")
    return text[:start] + block + text[end + len(README_END):]
