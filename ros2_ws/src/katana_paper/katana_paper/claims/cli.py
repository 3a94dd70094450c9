"""The `claims` subcommands: `katana-curiosity claims RUN_DIR` (section 3.2) and `katana-robot
claims RUN_DIR` (section 3.3). Each prints the report and writes claims.json and claims.md
into RUN_DIR, beside summary.json."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from katana_common.cli_args import non_negative_int, positive_int

from . import abstract, robot, stats
from .core import Settings, finish

#: where `katana-robot claims` looks for the truth when neither --truth nor the summary names
#: one that exists
DEFAULT_TRUTH = Path("docs/robot_truth.json")


def _folder(text: str) -> Path:
    path = Path(text)
    if not path.is_dir():
        raise argparse.ArgumentTypeError(f"no folder {text}")
    return path


def _band(text: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LOW,HIGH, got {text!r}") from None
    if not 0.0 <= lo < hi <= 1.0:
        raise argparse.ArgumentTypeError(f"need 0 <= LOW < HIGH <= 1, got {text!r}")
    return lo, hi


def add_common(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("run_dir", type=_folder, metavar="RUN_DIR", help=what)
    p.add_argument("--resamples", type=positive_int, default=stats.RESAMPLES,
                   help="bootstrap resamples per claim")
    p.add_argument("--bootstrap-seed", type=non_negative_int, default=stats.SEED,
                   help="seed of the resampling (the verdicts are reproducible)")


def add_curiosity_claims(sub) -> None:
    p = sub.add_parser("claims", help="the claims of section 3.2 from a `paper` output folder "
                       "as statistics: claims.json and claims.md beside its summary.json")
    add_common(p, "a `katana-curiosity paper` output folder (summary.json, runs/*.csv)")


def add_robot_claims(sub) -> None:
    p = sub.add_parser("claims", help="the claims of section 3.3 from a `paper` output folder "
                       "as statistics: claims.json and claims.md beside its summary.json")
    add_common(p, "a `katana-robot paper` output folder (runs/<strategy>-s<seed>/)")
    p.add_argument("--truth", type=Path, default=None,
                   help="the measured truth (default: the one summary.json names, else "
                   f"{DEFAULT_TRUTH})")
    p.add_argument("--uncertain", type=_band, default=None, metavar="LOW,HIGH",
                   help="P(stays) band of the truth's uncertain pairs (default 0.05,0.95)")


def _settings(args) -> Settings:
    return Settings(resamples=args.resamples, seed=args.bootstrap_seed)


def _options(args, defaults: dict) -> str:
    """The options that differ from their defaults, for the command claims.json records."""
    parts = []
    for name, default in defaults.items():
        value = getattr(args, name, default)
        if value is not None and value != default:
            text = ",".join(f"{v:g}" for v in value) if isinstance(value, tuple) else value
            parts.append(f"--{name.replace('_', '-')} {text}")
    return "".join(f" {p}" for p in parts)


def cmd_curiosity_claims(args) -> int:
    command = f"katana-curiosity claims {args.run_dir}" + _options(
        args, {"resamples": stats.RESAMPLES, "bootstrap_seed": stats.SEED})
    try:
        doc = abstract.claims_document(args.run_dir, _settings(args), command)
    except (OSError, ValueError) as exc:
        print(f"katana-curiosity claims: {exc}", file=sys.stderr)
        return 2
    return finish(args.run_dir, doc, "katana-curiosity claims")


def robot_truth_path(args, summary: dict | None) -> Path | None:
    """--truth, else the truth summary.json names (as given, or beside the run folder), else
    docs/robot_truth.json; None when none of them exists."""
    if args.truth is not None:
        return args.truth if args.truth.exists() else None
    named = (summary or {}).get("truth")
    for candidate in ([Path(named), args.run_dir / named] if named else []) + [DEFAULT_TRUTH]:
        if candidate.exists():
            return candidate
    return None


def cmd_robot_claims(args) -> int:
    try:
        loaded = robot.load_folder(args.run_dir)
        truth = robot_truth_path(args, loaded[0])
        if truth is None:
            print("katana-robot claims: no measured truth (pass --truth, or run `katana-robot "
                  "truth`)", file=sys.stderr)
            return 2
        command = f"katana-robot claims {args.run_dir} --truth {truth}" + _options(
            args, {"resamples": stats.RESAMPLES, "bootstrap_seed": stats.SEED,
                   "uncertain": robot.UNCERTAIN})
        doc = robot.claims_document(args.run_dir, truth, _settings(args),
                                    args.uncertain or robot.UNCERTAIN, command, loaded)
    except (OSError, ValueError) as exc:
        print(f"katana-robot claims: {exc}", file=sys.stderr)
        return 2
    return finish(args.run_dir, doc, "katana-robot claims")
