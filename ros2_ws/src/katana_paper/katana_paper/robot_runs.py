"""`katana-robot paper`: one whole graph (`katana-demo`) per strategy and seed, each in its own
process and ROS domain, J at a time, then every run's experience log replayed against the
measured truth.

Writes DIR/summary.json, DIR/runs/<strategy>-s<seed>/ (the run) and <strategy>-s<seed>.csv (per
experiment: choice, outcome, KL per height), kl.png (cf. Figures 5/9), experience.png (Figure
4), model.png (Figure 13), truth.png and contact_sheet.png (12 consecutive experiments of the
first run in the paper's four columns, cf. Figures 10-12).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from katana_bringup.run import default_params_files, load_params
from katana_curiosity.core.predictors import ALPHA, THETA_ROBOT
from katana_curiosity.core.run_record import LOG_NAME, ExperienceLog

from . import robot_paper as rp
from .contact_sheet import ContactSheetRecorder, contact_sheet
from .robot_truth import TruthTable

#: a run and the strategy and seed it was made with
Job = tuple[str, int]


def run_name(strategy: str, seed: int) -> str:
    return f"{strategy}-s{seed}"


def _launch(strategy: str, seed: int, experiments: int, run_dir: Path, domain: int,
            extra: Sequence[str]) -> subprocess.Popen:
    run_dir.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    cmd = [shutil.which("katana-demo") or "katana-demo", "--experiments", str(experiments),
           "--strategy", strategy, "--seed", str(seed), "--out", str(run_dir), *extra]
    log = open(run_dir / "stdout.log", "w", encoding="utf-8")  # noqa: SIM115 (closed by caller)
    proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT)
    proc.log = log  # type: ignore[attr-defined]
    return proc


def _end(proc: subprocess.Popen, grace_s: float = 10.0) -> int:
    """SIGINT (katana-demo keeps what it recorded), then SIGKILL after `grace_s`."""
    proc.send_signal(signal.SIGINT)
    try:
        code = proc.wait(timeout=grace_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        code = proc.wait()
    proc.log.close()
    return code


def _complete(run: Path, experiments: int) -> bool:
    log = run / LOG_NAME
    return log.exists() and len(ExperienceLog(log)) >= experiments


def _say(text: str) -> None:
    print(f"katana-robot paper: {text}", flush=True)


def run_all(jobs: Sequence[Job], experiments: int, out: Path, parallel: int,
            domain_base: int, timeout_s: float, contact_first: int | None,
            reuse: bool = False) -> dict[str, int]:
    """Each (strategy, seed) a katana-demo in its own process and ROS domain, `parallel` at a
    time; the first job also feeds a contact-sheet recorder. Returns exit codes by run."""
    pending = list(jobs)
    running: dict[int, tuple[str, subprocess.Popen, float]] = {}
    codes: dict[str, int] = {}
    recorder = None
    try:
        while pending or running:
            for slot in range(parallel):
                if slot in running or not pending:
                    continue
                strategy, seed = pending.pop(0)
                name = run_name(strategy, seed)
                if reuse and _complete(out / "runs" / name, experiments):
                    codes[name] = 0
                    _say(f"{name} is complete already; reused")
                    continue
                if contact_first is not None and recorder is None and not running:
                    # the first run launched (reused ones are complete already)
                    recorder = ContactSheetRecorder(domain_base + slot, contact_first)
                proc = _launch(strategy, seed, experiments, out / "runs" / name,
                               domain_base + slot, [])
                running[slot] = (name, proc, time.monotonic())
                _say(f"started {name} (domain {domain_base + slot})")
            for slot, (name, proc, t0) in list(running.items()):
                code = proc.poll()
                if code is None and time.monotonic() - t0 > timeout_s:
                    code = _end(proc)
                if code is not None:
                    if not proc.log.closed:
                        proc.log.close()
                    codes[name] = code
                    del running[slot]
                    _say(f"{name} ended ({code}) after {time.monotonic() - t0:.0f} s")
            time.sleep(0.2)
    finally:
        for name, proc, _ in running.values():
            _end(proc)
            codes.setdefault(name, -15)
        if recorder is not None:
            recorder.close()
            if recorder.rows:
                contact_sheet(recorder.rows, out / "contact_sheet.png")
    return codes


def query_rule() -> tuple[float, float]:
    """The curiosity node's alpha and theta on the robot, as the packaged graph sets them."""
    params = load_params(default_params_files("sim")).get("curiosity_node", {})
    return float(params.get("alpha", ALPHA)), float(params.get("theta", THETA_ROBOT))


def analyse(out: Path, jobs: Sequence[Job], truth_path: Path, experiments: int,
            seeds: Sequence[int]) -> dict:
    """summary.json, the per-run CSVs and the figures from the runs in out/runs."""
    truth = TruthTable.load(truth_path)
    alpha, theta = query_rule()
    analyses = []
    for strategy, seed in jobs:
        run = out / "runs" / run_name(strategy, seed)
        records = ExperienceLog(run / LOG_NAME).records if (run / LOG_NAME).exists() else []
        a = rp.analyse_run(records, truth, strategy, seed, alpha=alpha, theta=theta)
        rp.write_run_csv(a, out / f"{run_name(strategy, seed)}.csv")
        analyses.append(a)
    summary = rp.summarise(analyses, experiments, seeds, str(truth_path))
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    usable = [a for a in analyses if len(a.states)]
    if usable:
        rp.kl_figure(usable, out / "kl.png")
        rp.experience_figure(usable, out / "experience.png", usable[0].strategy)
        rp.model_figure(usable[0], truth, out / "model.png")
    rp.truth_figure(truth, out / "truth.png")
    return summary


def _interrupt(_signum, _frame):  # SIGTERM: end the runs as Ctrl-C does
    raise KeyboardInterrupt


def cmd_paper(args) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    truth = Path(args.truth)
    if not truth.exists():
        print(f"katana-robot paper: no measured truth at {truth}; run `katana-robot truth` "
              "first or pass --truth", file=sys.stderr)
        return 2
    strategies = [m.strip() for m in args.strategies.split(",") if m.strip()]
    seeds = list(range(args.seed0, args.seed0 + args.seeds))
    jobs = [(m, s) for s in seeds for m in strategies]
    start = time.monotonic()
    signal.signal(signal.SIGTERM, _interrupt)
    try:
        codes = run_all(jobs, args.experiments, out, args.jobs, args.domain_base,
                        args.run_timeout or 30.0 * args.experiments + 120.0,
                        None if args.no_contact_sheet else args.contact_first, args.reuse)
    except KeyboardInterrupt:
        print("katana-robot paper: interrupted; analysing what was recorded", file=sys.stderr)
        codes = {"interrupted": 130}
    wall = time.monotonic() - start
    summary = analyse(out, jobs, truth, args.experiments, seeds)
    summary["wall_s"] = round(wall, 1)
    summary["jobs"] = args.jobs
    summary["exit_codes"] = codes
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    for strategy, m in summary["strategies"].items():
        _say(f"{strategy}: final KL {m['final_kl']} (overall {m['final_kl_overall']}), highest "
             f"stack {m['highest_stack']}, {m['s_per_experiment']} s/experiment, wasted "
             f"{m['wasted_share']}")
    _say(f"{len(jobs)} runs in {wall:.0f} s -> {out}/summary.json")
    return 0 if all(c == 0 for c in codes.values()) else 1
