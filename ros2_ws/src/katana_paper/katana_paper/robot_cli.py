"""katana-robot: the paper's robot experiment (sections 2.2 and 3.3) reproduced and measured.

    katana-robot truth --trials 30 --out DIR        the ground truth of the simulated world
    katana-robot paper --seeds 4 --experiments 60 --strategies q1,random --jobs 2 --out DIR
    katana-robot skill --goal-height 3 --trials 10 --model RUN_DIR [--out DIR]
    katana-robot claims RUN_DIR [--truth PATH]

`truth` (katana_paper.truth) measures in the fast sim, per (height, action) the fovea can
realise, how often a placement stays: truth.json and truth.png. `paper` (katana_paper.
robot_runs) runs one whole graph per strategy and seed, each a Ray task in its own process and
ROS domain (a local Ray, or a cluster by --address), and replays every run against the measured
truth: summary.json, per-run CSVs, the figures and a contact sheet. `skill`
(katana_paper.skill_trials) sends build_stack goals to skill_node with the model a run learned
and with an untrained one: skill.json. `claims` (katana_paper.claims) replays a `paper`
folder's runs against the truth and judges the claims of section 3.3 with bootstrap intervals
over the seeds: claims.json and claims.md beside summary.json.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from katana_common.cli_args import (
    CommandLineError,
    comma_list,
    int_in,
    non_negative_int,
    parse_command_line,
    positive_int,
    positive_seconds,
    readable_file,
    writable_folder,
)
from katana_curiosity.core.strategies import STRATEGIES

from .claims.cli import add_robot_claims, cmd_robot_claims
from .robot_runs import cmd_paper
from .skill_trials import cmd_skill
from .truth import cmd_truth

COMMANDS = {"truth": cmd_truth, "paper": cmd_paper, "skill": cmd_skill,
            "claims": cmd_robot_claims}
#: where `paper` looks for the measured truth without --truth (what `truth` writes by default)
DEFAULT_TRUTH = "runs/robot-truth/truth.json"
#: ROS 2's highest domain id (the parallel runs take --domain-base .. + --jobs - 1, below it)
MAX_DOMAIN = 232


def _add_truth(sub) -> None:
    t = sub.add_parser("truth", help="measure P(stays) per (height, action) in the sim")
    t.add_argument("--trials", type=positive_int, default=30, help="placements per pair")
    t.add_argument("--out", type=writable_folder, default="runs/robot-truth")
    t.add_argument("--seed", type=non_negative_int, default=0, help="first reset seed")
    t.add_argument("--max-height", type=int, default=3, choices=range(1, 4))
    t.add_argument("--actions", type=int, default=6, choices=(6,))


def _add_paper(sub) -> None:
    p = sub.add_parser("paper", help="multi-seed robot runs against the measured truth")
    p.add_argument("--seeds", type=positive_int, default=4)
    p.add_argument("--seed0", type=non_negative_int, default=0, help="first seed")
    p.add_argument("--experiments", type=positive_int, default=60)
    p.add_argument("--strategies", "--methods", dest="strategies", default="q1,random",
                   type=comma_list(STRATEGIES, "strategy"),
                   help=f"comma-separated, from {','.join(STRATEGIES)}")
    p.add_argument("--jobs", type=positive_int, default=2,
                   help="runs at a time on each machine (CPUs of the local Ray, ROS domains)")
    p.add_argument("--address", default=None,
                   help="an existing Ray cluster (e.g. ray://head:10001 or auto; --out must be "
                        "on a folder every machine sees); default: a local Ray")
    p.add_argument("--out", type=writable_folder, default="runs/robot-paper",
                   help="output folder (an existing one resumes: each run continues its log)")
    p.add_argument("--truth", type=readable_file, default=None,
                   help=f"the measured truth (default {DEFAULT_TRUTH}, what `truth` writes)")
    p.add_argument("--domain-base", type=int_in(0, MAX_DOMAIN), default=None,
                   help="ROS domain of the first parallel slot (default: $ROS_DOMAIN_ID)")
    p.add_argument("--run-timeout", type=positive_seconds, default=None, metavar="S")
    p.add_argument("--contact-first", type=non_negative_int, default=0,
                   help="first experiment of the contact sheet (first run)")
    p.add_argument("--no-contact-sheet", action="store_true")
    p.add_argument("--reuse", action="store_true",
                   help="keep runs whose log already holds --experiments (re-analyse only)")


def _add_skill(sub) -> None:
    s = sub.add_parser("skill", help="build_stack with a learned and an untrained model")
    s.add_argument("--goal-height", type=int, default=3, choices=range(1, 5))
    s.add_argument("--trials", type=positive_int, default=10)
    s.add_argument("--model", type=_model, required=True,
                   help="a run folder (learner.npz) or a file")
    s.add_argument("--seed", type=non_negative_int, default=100,
                   help="reset seed of the first trial")
    s.add_argument("--max-placements", type=positive_int, default=12)
    s.add_argument("--out", type=writable_folder, default="runs/robot-skill")
    s.add_argument("--no-untrained", action="store_true")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="katana-robot", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    _add_truth(sub)
    _add_paper(sub)
    _add_skill(sub)
    add_robot_claims(sub)
    return parser


def _model(text: str) -> Path:
    """A learned model: a run folder holding learner.npz, or the file itself."""
    model = Path(text)
    if not text or not ((model / "learner.npz").is_file() or model.is_file()):
        raise argparse.ArgumentTypeError(f"no learner.npz in {text!r} (a run folder or the file)")
    return model


def _check(args) -> None:
    """What argparse cannot check alone, across options and the environment (run by
    cli_args.parse_command_line before any work: the refusal names the option)."""
    if args.command != "paper":
        return
    if args.truth is None:
        try:
            args.truth = readable_file(DEFAULT_TRUTH)
        except argparse.ArgumentTypeError:
            raise CommandLineError("--truth", f"no measured truth at {DEFAULT_TRUTH}; run "
                                   "`katana-robot truth` first or pass --truth") from None
    if args.domain_base is None:
        try:
            args.domain_base = int_in(0, MAX_DOMAIN)(os.environ.get("ROS_DOMAIN_ID") or "0")
        except argparse.ArgumentTypeError as err:
            raise CommandLineError("--domain-base", f"(default $ROS_DOMAIN_ID) {err}") from None
    if args.domain_base + args.jobs > MAX_DOMAIN:
        raise CommandLineError("--domain-base", f"{args.domain_base} leaves no room for --jobs "
                               f"{args.jobs} domains below {MAX_DOMAIN}")


def main(argv: list[str] | None = None) -> int:
    args = parse_command_line(build_parser(), sys.argv[1:] if argv is None else argv, [_check])
    return COMMANDS[args.command](args)


if __name__ == "__main__":
    sys.exit(main())
