"""`katana-robot paper`: one whole graph (`katana-demo`) per strategy and seed, each a Ray task
(local, or a cluster by `--address`) in its own process and ROS domain, J at a time per
machine, then every run's experience log replayed against the measured truth. An interrupted
study resumes: every run continues its own log.

Writes DIR/summary.json, DIR/runs/<strategy>-s<seed>/ (the run) and <strategy>-s<seed>.csv (per
experiment: choice, outcome, KL per height), kl.png (cf. Figures 5/9), experience.png (Figure
4), model.png (Figure 13), truth.png and contact_sheet.png (12 consecutive experiments of the
first run in the paper's four columns, cf. Figures 10-12).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import fcntl
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path

from katana_bringup.run import default_params_files, load_params
from katana_curiosity.core.predictors import ALPHA, THETA_ROBOT
from katana_curiosity.core.run_record import LOG_NAME, ExperienceLog

from . import robot_paper as rp
from .ray_session import ray_session
from .robot_truth import TruthTable

#: a run and the strategy and seed it was made with
Job = tuple[str, int]


def run_name(strategy: str, seed: int) -> str:
    return f"{strategy}-s{seed}"


def _die_with_parent() -> None:
    """In the child before exec: SIGINT when the process that started it dies (a Ray worker
    killed by a cancel or a shutdown), so that no katana-demo outlives its task."""
    libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    libc.prctl(1, signal.SIGINT)  # PR_SET_PDEATHSIG


def _launch(strategy: str, seed: int, experiments: int, run_dir: Path, domain: int,
            extra: Sequence[str]) -> subprocess.Popen:
    run_dir.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    cmd = [shutil.which("katana-demo") or "katana-demo", "--experiments", str(experiments),
           "--strategy", strategy, "--seed", str(seed), "--out", str(run_dir), *extra]
    log = open(run_dir / "stdout.log", "a", encoding="utf-8")  # noqa: SIM115 (closed by caller)
    proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT,
                            preexec_fn=_die_with_parent if sys.platform == "linux" else None)
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


@contextmanager
def leased_domain(domains: Sequence[int], poll_s: float = 0.5) -> Iterator[int]:
    """A ROS domain of `domains` no other run on this machine holds, for as long as the run
    lasts: an exclusive lock on a file per domain in the temporary folder (released by the
    kernel if the holder dies). Waits while all are taken."""
    folder = Path(tempfile.gettempdir())
    while True:
        for domain in domains:
            handle = open(folder / f"katana-ros-domain-{domain}.lock", "a")  # noqa: SIM115
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                handle.close()
                continue
            try:
                yield domain
            finally:
                fcntl.flock(handle, fcntl.LOCK_UN)
                handle.close()
            return
        time.sleep(poll_s)


@dataclass(frozen=True)
class RunTask:
    """One robot run as a Ray task: what to run and where its records go."""

    strategy: str
    seed: int
    experiments: int
    run_dir: str
    domains: tuple[int, ...]
    timeout_s: float
    contact_first: int | None = None  # record the contact sheet of this run from there
    contact_sheet: str = ""  # where it goes


def run_task(task: RunTask) -> tuple[str, int, float]:
    """Run one katana-demo in a leased ROS domain until it ends or times out; returns (name,
    exit code, seconds). Cancelling the task (KeyboardInterrupt) ends the run as Ctrl-C does."""
    name = run_name(task.strategy, task.seed)
    start = time.monotonic()
    contact = ([] if task.contact_first is None else
               ["--contact-sheet", task.contact_sheet, "--contact-first", str(task.contact_first)])
    with leased_domain(task.domains) as domain:
        proc = _launch(task.strategy, task.seed, task.experiments, Path(task.run_dir), domain,
                       contact)
        try:
            while (code := proc.poll()) is None:
                if time.monotonic() - start > task.timeout_s:
                    code = _end(proc)
                    break
                time.sleep(0.2)
        finally:
            if proc.poll() is None:
                code = _end(proc)
            if not proc.log.closed:
                proc.log.close()
    return name, int(code), time.monotonic() - start


def run_all(jobs: Sequence[Job], experiments: int, out: Path, parallel: int,
            domain_base: int, timeout_s: float, contact_first: int | None,
            reuse: bool = False, address: str | None = None) -> dict[str, int]:
    """Each (strategy, seed) a Ray task running katana-demo in its own ROS domain (`parallel`
    domains from `domain_base` per machine, and as many CPUs on a local Ray); the first run
    launched also draws the contact sheet (katana-demo --contact-sheet). Returns exit codes by
    run. On a cluster (`address`), `out` must be a folder every machine sees at the same
    path."""
    codes: dict[str, int] = {}
    todo = []
    for strategy, seed in jobs:
        name = run_name(strategy, seed)
        if reuse and _complete(out / "runs" / name, experiments):
            codes[name] = 0
            _say(f"{name} is complete already; reused")
            continue
        todo.append(RunTask(strategy, seed, experiments, str(out / "runs" / name),
                            tuple(range(domain_base, domain_base + parallel)), timeout_s))
    if todo and contact_first is not None:
        todo[0] = replace(todo[0], contact_first=contact_first,
                          contact_sheet=str(out / "contact_sheet.png"))
    if not todo:
        return codes
    with ray_session(address, parallel) as ray:
        remote = ray.remote(num_cpus=1, max_retries=0)(run_task)
        pending = {remote.remote(task): run_name(task.strategy, task.seed) for task in todo}
        _say(f"submitted {len(pending)} runs: {', '.join(pending.values())}")
        try:
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1)
                name, code, wall_s = ray.get(ready[0])
                del pending[ready[0]]
                codes[name] = code
                _say(f"{name} ended ({code}) after {wall_s:.0f} s")
        finally:
            for ref in pending:  # interrupted: every run still going ends as Ctrl-C ends it
                ray.cancel(ref)
            if pending:
                ray.wait(list(pending), num_returns=len(pending), timeout=30.0)
            for name in pending.values():
                codes.setdefault(name, -15)
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
                        None if args.no_contact_sheet else args.contact_first, args.reuse,
                        args.address)
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
