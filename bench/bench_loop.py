"""The whole loop on the simulated arm: seconds per experiment and the stages of one.

Runs `katana-demo` (every node in one process, headless, real_time_factor 0) for a number of
experiments and reads the stage times the curiosity node logs with each experiment. The
perception and planning figures are measured in-process on the same kind of input.
"""

from __future__ import annotations

import importlib.util
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

EXPERIMENTS = 30
TARGETS = {"s_per_experiment": 1.0, "perception_ms": 10.0}


def _median(values: list[float]) -> float | None:
    return statistics.median(values) if values else None


def _perception_ms() -> float:
    path = Path(__file__).with_name("bench_perception.py")
    spec = importlib.util.spec_from_file_location("bench_perception", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return float(module.run()["perception_ms"])


def _plan_ms(records: list[dict], calls: int = 500) -> float:
    from katana_curiosity.core.planner import Planner
    from katana_curiosity.core.predictors import PredictorBank, QueryRule, one_hot_with_bias
    from katana_curiosity.core.run_record import replay

    bank = PredictorBank(range(4), one_hot_with_bias(6), QueryRule(1.0, 0.1), n_states=5)
    replay(bank, records)
    planner = Planner(bank, top=4)
    times = []
    for i in range(calls):
        bank.update(i % 4, i % 6, 1.0 if i % 3 else -1.0)
        start = time.perf_counter()
        planner.solve()
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1e3


def run() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        start = time.perf_counter()
        proc = subprocess.run(
            [sys.executable, "-m", "katana_bringup.demo", "--experiments", str(EXPERIMENTS),
             "--out", str(out)],
            capture_output=True, text=True, timeout=60 * EXPERIMENTS,
        )
        wall = time.perf_counter() - start
        if proc.returncode != 0:
            raise RuntimeError(f"katana-demo failed: {proc.stderr[-2000:]}")
        records = [json.loads(line) for line in (out / "experience.jsonl").read_text().splitlines()]
        summary = json.loads((out / "summary.json").read_text())

    def stage(name: str) -> list[float]:
        return [r["stage_s"][name] for r in records if name in r.get("stage_s", {})]

    gaps = [b["wall_time"] - a["wall_time"] for a, b in zip(records, records[1:], strict=False)]
    dropped = sum(int(x) for x in stage("dropped_before"))
    return {
        "experiments": len(records),
        "s_per_experiment": _median(gaps),
        "s_per_experiment_mean": statistics.mean(gaps) if gaps else None,
        "experiment_s_without_waits": _median(stage("experiment_s")),
        "perception_ms": _perception_ms(),
        "observe_ms": _median([v * 1e3 for v in stage("observe_s")]),
        "plan_ms": _plan_ms(records),
        "pick_place_s": _median(stage("pick_place_s")),
        "settle_s": _median(stage("settle_s")),
        "judge_ms": _median([v * 1e3 for v in stage("judge_s")]),
        "dropped_experiments": dropped,
        "highest_stack": summary["highest_stack"],
        "heights_explored": summary["heights_explored"],
        "run_wall_s": round(wall, 1),
        "targets": TARGETS,
        "notes": f"katana-demo --experiments {EXPERIMENTS}, sim at real_time_factor 0, every "
                 "node in one process; s_per_experiment is the median wall time between "
                 "consecutive logged experiments (dropped attempts included); stage figures are "
                 "medians of what the curiosity node logged; perception_ms is the segmentation of "
                 "one 640x480 sim frame (bench_perception); plan_ms is one Planner.solve at 4 "
                 "heights x 6 actions on the model the run learned.",
    }


if __name__ == "__main__":
    print(json.dumps(run(), indent=2))
