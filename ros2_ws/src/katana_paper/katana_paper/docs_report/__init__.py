"""docs/BENCHMARKS.md, docs/REPRODUCING.md and the results block of README.md, generated from
committed result files, so that every published figure comes from a file and stands beside the
command and the CPU that made it.

    python -m katana_paper.docs_report                 # write the three from the committed files
    python -m katana_paper.docs_report --check         # exit 1 if one is not what the files make
    python -m katana_paper.docs_report collect paper core ...
                                                       # copy fresh results in, then write

The committed result files (`SOURCES`) are the benches' JSON (`python bench/run.py NAME` writes
bench/results/NAME.json), the summaries of `make paper`, `make robot-paper` and `katana-robot
skill`, the claims.json that `katana-curiosity claims` and `katana-robot claims` write beside
the first two (the pages' claim verdicts, collected as paper-claims and robot-paper-claims),
and the measured truth docs/robot_truth.json. A file that is not there is reported as
"not measured", with the command that makes it. Bench results record their machine; `collect`
adds the machine it runs on to a file that does not (so run it where the results were made).
The pages are pure functions of the loaded files, tested on small constructed inputs.

The package is split by job: `sources` (the result files, loading, `collect`), `formatting`,
`provenance` (the CPU and the command behind a file), `benchmarks` (BENCHMARKS.md), `claims`
(the paper's claims as the committed claims.json files judge them), `reproducing`,
`reproducing_robot` and `reproducing_text` (REPRODUCING.md: the abstract world, the robot,
the prose), `readme` (README.md's block) and `cli` (the command). Everything is re-exported here.
"""

from __future__ import annotations

from .benchmarks import (
    BENCH_ABOUT,
    BENCH_RENDER,
    BENCHMARKS_INTRO,
    SPEED_HEADER,
    bench_arm,
    bench_core,
    bench_driver,
    bench_loop,
    bench_perception,
    bench_record,
    bench_sim,
    render_benchmarks,
)
from .claims import (
    PAPER_ORDER,
    RunSection,
    claims_counts,
    claims_mismatch,
    claims_section,
    ranking,
    uncertain_pairs,
)
from .cli import find_root, main, render_all
from .formatting import (
    NONE_MEASURED,
    NOT_RECORDED,
    count_of,
    display,
    experiments_of,
    get,
    met_text,
    num,
    ratio,
    strategies_of,
    table,
)
from .provenance import (
    EXPERIMENTS_FLAG,
    STRATEGIES_FLAG,
    bench_command,
    cpu_text,
    machine_of,
    made_by,
    not_measured,
    paper_command,
    robot_paper_command,
    skill_command,
    truth_command,
)
from .readme import claim_rows, readme_rows, render_readme_block, splice_readme
from .reproducing import baselines_section, kl_table, paper_section, render_reproducing
from .reproducing_robot import (
    parallax_actions,
    robot_runs_table,
    robot_section,
    skill_section,
    truth_section,
    truth_table,
)
from .reproducing_text import (
    BASELINES_ABOUT,
    DEVIATIONS,
    FAITHFULNESS,
    PAPER_CLAIMS,
    PAPER_TABLE,
    REPRODUCING_INTRO,
    ROBOT_CLAIMS,
    ROBOT_TABLE,
    SECTION_32_HOW,
    SECTION_33_HOW,
    SKILL_ABOUT,
    TRUTH_ABOUT,
    TRUTH_PARALLAX,
)
from .sources import (
    BENCHES,
    BENCHMARKS_MD,
    GENERATED,
    README_BEGIN,
    README_END,
    README_MD,
    REPRODUCING_MD,
    SOURCES,
    Source,
    collect,
    load_results,
    machine_info,
)

__all__ = [
    "BENCHES", "BENCHMARKS_MD", "GENERATED", "README_BEGIN", "README_END", "README_MD",
    "REPRODUCING_MD", "SOURCES", "Source", "collect", "load_results", "machine_info",
    "NONE_MEASURED", "NOT_RECORDED", "count_of", "display", "experiments_of", "get",
    "met_text", "num", "ratio", "strategies_of", "table",
    "EXPERIMENTS_FLAG", "STRATEGIES_FLAG", "bench_command", "cpu_text", "machine_of",
    "made_by", "not_measured", "paper_command", "robot_paper_command", "skill_command",
    "truth_command",
    "BENCHMARKS_INTRO", "BENCH_ABOUT", "BENCH_RENDER", "SPEED_HEADER", "bench_arm",
    "bench_core", "bench_driver", "bench_loop", "bench_perception", "bench_record",
    "bench_sim",
    "render_benchmarks",
    "PAPER_ORDER", "RunSection", "claims_counts", "claims_mismatch", "claims_section", "ranking",
    "uncertain_pairs",
    "BASELINES_ABOUT", "DEVIATIONS", "FAITHFULNESS", "PAPER_CLAIMS", "PAPER_TABLE",
    "REPRODUCING_INTRO", "ROBOT_CLAIMS", "ROBOT_TABLE", "SECTION_32_HOW", "SECTION_33_HOW",
    "SKILL_ABOUT", "TRUTH_ABOUT", "TRUTH_PARALLAX",
    "baselines_section", "kl_table", "paper_section", "render_reproducing",
    "parallax_actions", "robot_runs_table", "robot_section", "skill_section", "truth_section",
    "truth_table",
    "claim_rows", "readme_rows", "render_readme_block", "splice_readme",
    "find_root", "main", "render_all",
]
