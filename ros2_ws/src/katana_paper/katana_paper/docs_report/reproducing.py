"""docs/REPRODUCING.md: how to reproduce each section of the paper, with the tables of the
committed runs and the claim verdicts between the fixed prose; this module writes the abstract
world's sections (3.2, the baselines) and assembles the page."""

from __future__ import annotations

from collections.abc import Mapping

from . import reproducing_text as prose
from .claims import RunSection, heights_of, ranking
from .formatting import Json, display, experiments_of, finite, get, num, strategies_of, table
from .provenance import made_by, not_measured, paper_command
from .reproducing_robot import (
    after30_section,
    robot_section,
    skill_section,
    study_section,
    truth_section,
)
from .sources import GENERATED


def kl_table(data: Json) -> str:
    """Final KL per height and overall of each strategy, the best overall in bold."""
    strategies = strategies_of(data)
    heights = heights_of(strategies)
    best = min((s.get("final_kl_overall") for s in strategies.values()
                if finite(s.get("final_kl_overall"))), default=None)
    rows = []
    for key, s in strategies.items():
        overall = s.get("final_kl_overall")
        cell = num(overall, 4)
        rows.append((display(key), *(num(get(s, "final_kl", h)) for h in heights),
                     f"**{cell}**" if overall == best else cell))
    return table(("strategy", *(f"height {h}" for h in heights), "overall"), rows)


def baselines_section(data: Json) -> str:
    """The baselines' run: its settings, the KL table and the strategies ranked."""
    if data is None:
        return not_measured("baselines")
    seeds = get(data, "seeds", default=[]) or []
    return "\n".join([
        f"{made_by(paper_command(data), data)} {len(seeds)} seeds x "
        f"{num(experiments_of(data))} steps per strategy.", "",
        kl_table(data), "",
        "Best overall first: " + ", ".join(display(k) for k in ranking(strategies_of(data)))
        + "."])


def _paper_settings(data: Json) -> str:
    p = get(data, "parameters", default={}) or {}
    seeds = get(data, "seeds", default=[]) or []
    return (f"{made_by(paper_command(data), data)} {len(seeds)} seeds x "
            f"{num(experiments_of(data))} steps per strategy; {p.get('n_blocks')} blocks, "
            f"{p.get('n_features')} features per height, alpha {p.get('alpha')}, "
            f"theta {p.get('theta')}, gamma {p.get('gamma')}.")


#: section 3.2's run: its settings, the KL table and the verdicts on the paper's claims (from
#: its claims.json)
paper_section = RunSection("paper", _paper_settings, prose.PAPER_TABLE, kl_table,
                           prose.PAPER_CLAIMS)


def render_reproducing(results: Mapping) -> str:
    """REPRODUCING.md: the prose of every section with the committed results between."""
    return "\n".join([
        GENERATED, "", prose.REPRODUCING_INTRO, "",
        "## Section 3.2: the simulated blocks world", "", prose.SECTION_32_HOW, "",
        paper_section(results.get("paper"), results.get("paper-claims")), "",
        "## Section 3.3: the robot, on the simulated Katana", "", prose.SECTION_33_HOW, "",
        "### The measured truth", "", prose.TRUTH_ABOUT, "",
        truth_section(results.get("robot-truth")), "",
        "### Runs against the truth", "",
        robot_section(results.get("robot-paper"), results.get("robot-paper-claims")), "",
        "### The study at the claims' scale", "", prose.STUDY_ABOUT, "",
        study_section(results.get("robot-study"), results.get("robot-study-claims")), "",
        "### The claim the study could decide with the fewest seeds", "", prose.AFTER30_ABOUT,
        "", after30_section(results.get("robot-after30"), results.get("robot-after30-claims")),
        "",
        "### The stacking skill (Figure 14)", "", prose.SKILL_ABOUT, "",
        skill_section(results.get("robot-skill")), "",
        "## Beyond the paper: baselines", "", prose.BASELINES_ABOUT, "",
        baselines_section(results.get("baselines")), "",
        prose.FAITHFULNESS, "", prose.DEVIATIONS,
    ]).rstrip() + "\n"
