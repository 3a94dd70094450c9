"""`katana-curiosity`: the paper's simulated experiments from the command line."""

from __future__ import annotations

import argparse
import sys
import time

from katana_common.cli_args import (
    CommandLineError,
    comma_list,
    float_in,
    fraction,
    non_negative_int,
    parse_command_line,
    positive_int,
    positive_number,
    writable_folder,
)
from katana_curiosity.core.abstract_world import AbstractBlocksWorld
from katana_curiosity.core.predictors import ALPHA, GAMMA, THETA_ABSTRACT
from katana_curiosity.core.strategies import STRATEGIES
from tqdm import tqdm

from .claims.cli import add_curiosity_claims, cmd_curiosity_claims
from .experiments import DEFAULT_STRATEGIES, RunConfig, run, run_many, save_results
from .sweep import DEFAULT_GRID, DEFAULT_SWEEP_STRATEGIES, SweepSpec, parse_grid_axis, run_sweep

#: experiments per run of `paper`, `explore` and `sweep`
EXPERIMENTS = 10_000


_discount = float_in(0.0, 1.0, high_open=True, what="a discount factor")
_strategy_names = comma_list(STRATEGIES, "strategy")


def _strategies(text: str) -> list[str]:
    """Comma-separated strategy names (any case), each once, in the order given."""
    names = _strategy_names(text.lower())
    return list(dict.fromkeys(m.strip() for m in names.split(",") if m.strip()))


def _grid_axis(text: str) -> tuple[str, tuple]:
    try:
        return parse_grid_axis(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _add_runs(p: argparse.ArgumentParser, seeds: int, strategies: str, per: str,
              where: str = "") -> None:
    """The options of a set of runs: their length, seeds, strategies and query rule, and
    the output folder. `--steps` and `--methods` are the old spellings, still accepted."""
    p.add_argument("--experiments", "--steps", dest="experiments", type=positive_int,
                   default=EXPERIMENTS, help="experiments per run")
    p.add_argument("--seeds", type=positive_int, default=seeds, help=f"runs per {per}")
    p.add_argument("--first-seed", type=non_negative_int, default=0, help="first seed, >= 0")
    p.add_argument("--strategies", "--methods", dest="strategies", type=_strategies,
                   default=_strategies(strategies),
                   help=f"comma-separated, from {','.join(STRATEGIES)}")
    p.add_argument("--alpha", type=positive_number, default=ALPHA,
                   help=f"query condition scale{where}")
    p.add_argument("--theta", type=fraction, default=THETA_ABSTRACT,
                   help=f"query threshold{where}, [0, 1]")
    p.add_argument("--gamma", type=_discount, default=GAMMA,
                   help=f"discount factor{where}, [0, 1)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="katana-curiosity",
        description="Curiosity-driven exploration in the paper's simulated blocks world "
        "(Ngo et al. 2013, section 3).",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    paper = sub.add_parser("paper", help="every strategy on every seed; summary, CSV, Figures 4-9")
    explore = sub.add_parser("explore", help="one Q1 run with a progress bar, and its figures")
    _add_runs(paper, 10, ",".join(DEFAULT_STRATEGIES), "strategy (seeds 0..K-1)")
    _add_runs(explore, 1, "q1", "strategy (seeds 0..K-1)")
    for p in (paper, explore):
        p.add_argument("--jobs", type=positive_int, default=1, help="worker processes")
        p.add_argument("--out", type=writable_folder, required=True, help="output folder")
        p.add_argument("--no-figures", action="store_true", help="write summary and CSV only")
    _add_sweep(sub)
    add_curiosity_claims(sub)
    return parser


def _add_sweep(sub) -> None:
    default_grid = " ".join(
        f"--grid {k}={','.join(f'{v:g}' for v in vs)}" for k, vs in DEFAULT_GRID.items()
    )
    p = sub.add_parser(
        "sweep",
        help="a parameter grid x seeds x strategies as Ray tasks; sweep.csv, summary.json, "
        "sensitivity.png (resumes)",
    )
    p.add_argument(
        "--grid",
        type=_grid_axis,
        action="append",
        help=f"NAME=V1,V2,... (repeat per axis; alpha, theta, gamma, n_blocks, n_features); "
        f"default {default_grid}",
    )
    _add_runs(p, 20, ",".join(DEFAULT_SWEEP_STRATEGIES), "cell and strategy",
              " where not swept")
    p.add_argument("--out", type=writable_folder, required=True,
                   help="output folder (resumed if it exists)")
    p.add_argument(
        "--address",
        default=None,
        help="an existing Ray cluster (e.g. ray://head:10001 or auto); default: a local Ray",
    )
    p.add_argument(
        "--num-cpus", type=positive_int, default=2, help="CPUs of the local Ray (no --address)"
    )
    p.add_argument("--no-figures", action="store_true", help="write sweep.csv and summary only")


def _check_sweep(args) -> None:
    """The sweep's grid with the other options (cli_args.parse_command_line, before any
    work): it leaves the SweepSpec in `args.spec`."""
    if args.command != "sweep":
        return
    grid = dict(args.grid) if args.grid else dict(DEFAULT_GRID)
    if args.grid and len(grid) != len(args.grid):
        raise CommandLineError("--grid", "each parameter may be given once")
    base = {k: getattr(args, k) for k in ("alpha", "theta", "gamma") if k not in grid}
    try:
        args.spec = SweepSpec(
            grid=grid,
            strategies=tuple(args.strategies),
            seeds=args.seeds,
            first_seed=args.first_seed,
            experiments=args.experiments,
            base=base,
        )
        for n_blocks, n_features in {(c.n_blocks, c.n_features) for c in args.spec.configs()}:
            AbstractBlocksWorld(n_blocks, n_features)  # the world's own bounds, checked now
    except ValueError as exc:
        raise CommandLineError("--grid", str(exc)) from None


def _sweep(args) -> int:
    start = time.perf_counter()
    summary = run_sweep(
        args.spec, args.out, address=args.address, num_cpus=args.num_cpus,
        figures=not args.no_figures
    )
    wall = time.perf_counter() - start
    for name, per_strategy in summary["by_parameter"].items():
        for strategy, values in per_strategy.items():
            text = "  ".join(f"{v}: {s['mean']:.4f}+-{s['std']:.4f}" for v, s in values.items())
            print(f"{strategy:>8} final KL by {name}: {text}")
    print(
        f"{summary['ran']} runs now, {summary['reused']} from {args.out}/sweep.csv, "
        f"in {wall:.1f} s; results in {args.out}/"
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    args = parse_command_line(build_parser(), argv, [_check_sweep])
    if args.command == "sweep":
        return _sweep(args)
    if args.command == "claims":
        return cmd_curiosity_claims(args)
    configs = [
        RunConfig(
            strategy=m,
            seed=s,
            experiments=args.experiments,
            alpha=args.alpha,
            theta=args.theta,
            gamma=args.gamma,
        )
        for m in args.strategies
        for s in range(args.first_seed, args.first_seed + args.seeds)
    ]
    start = time.perf_counter()
    if args.command == "explore" and len(configs) == 1:
        results = _explore_with_progress(configs[0])
    else:
        with tqdm(total=len(configs), desc="runs", unit="run", file=sys.stderr) as bar:
            results = run_many(configs, jobs=args.jobs, progress=lambda r: bar.update(1))
    summary = save_results(results, args.out)
    if not args.no_figures:
        from .figures import paper_figures  # noqa: PLC0415 - matplotlib only when figures are wanted

        paper_figures(results, args.out, jobs=args.jobs)
    wall = time.perf_counter() - start
    for strategy, m in summary["strategies"].items():
        kl = " ".join(f"{h}:{v:.3f}" for h, v in m["final_kl"].items())
        print(f"{strategy:>6}: final KL overall {m['final_kl_overall']:.4f}  per height {kl}")
    print(f"{len(configs)} runs x {args.experiments} experiments in {wall:.1f} s; "
          f"results in {args.out}/")
    return 0


def _explore_with_progress(config: RunConfig) -> list:
    """One run with a progress bar over its experiments."""
    with tqdm(
        total=config.experiments,
        desc=f"{config.strategy} seed {config.seed}",
        unit="experiment",
        file=sys.stderr,
        mininterval=0.2,
    ) as bar:
        return [run(config, progress=bar.update,
                    progress_every=max(config.experiments // 200, 1))]


if __name__ == "__main__":
    sys.exit(main())
