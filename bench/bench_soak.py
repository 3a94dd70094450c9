"""A long fast-sim run: is the loop as fast, as small and as quick to record at its end as at
its start?

Runs `katana-demo` in this process (every node in one process, headless, real_time_factor 0,
seed 0, going on once every pair is known) for EXPERIMENTS experiments (SOAK_EXPERIMENTS in the
environment overrides it) and reports per block of BLOCK experiments: the seconds per
experiment (median gap between logged experiments) beside that block's floor (the median time
inside physics, renders, segmentation, the judge and the fovea per experiment, measured as
bench_loop measures it), the resident memory of the process (every node is in it) when the
block ended, and the time inside the experience log's append (write, flush, fsync) and the
checkpoint's save per experiment, with the bytes each wrote. The first block is the floor of
the last: a loop that slows, grows or writes more as its log grows shows it there; the floor
per block tells a slower loop from a busier machine.
"""

from __future__ import annotations

import json
import os
import statistics
import threading
import time
from pathlib import Path

from bench_loop import Meter, demo_run
from katana_curiosity import curiosity_node
from katana_curiosity.core import run_record

EXPERIMENTS = int(os.environ.get("SOAK_EXPERIMENTS", "1000"))
BLOCK = 100 if EXPERIMENTS >= 200 else max(EXPERIMENTS // 4, 1)
TARGETS = {"last_over_first_s_per_experiment": 1.1, "rss_growth_mib": 50.0,
           "last_over_first_write_s": 1.5}


def rss_mib() -> float:
    """This process's resident memory, MiB (VmRSS)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


class Writes:
    """Times the log's append and the checkpoint's save, and samples the RSS and the work the
    meter has counted after every experiment (the append is the moment an experiment is
    logged)."""

    def __init__(self, meter: Meter) -> None:
        self.meter = meter
        self.work_s: list[float] = []  # the meter's seconds of work when each was logged
        self.appends: list[tuple[float, int]] = []  # (seconds, bytes the log grew by)
        self.saves: list[tuple[float, int]] = []  # (seconds, bytes of the checkpoint)
        self.rss: list[float] = []
        self._lock = threading.Lock()
        self._undo: list[tuple[object, str, object]] = []

    def install(self) -> None:
        append = run_record.ExperienceLog.append
        save = curiosity_node.save_checkpoint
        writes = self

        def timed_append(log, record):
            before = log.path.stat().st_size if log.path.exists() else 0
            start = time.perf_counter()
            append(log, record)
            seconds = time.perf_counter() - start
            with writes._lock:
                writes.appends.append((seconds, log.path.stat().st_size - before))
                writes.rss.append(rss_mib())
                writes.work_s.append(sum(writes.meter.totals.values()))

        def timed_save(path, *args, **kwargs):
            start = time.perf_counter()
            save(path, *args, **kwargs)
            seconds = time.perf_counter() - start
            with writes._lock:
                writes.saves.append((seconds, Path(path).stat().st_size))

        self._patch(run_record.ExperienceLog, "append", timed_append)
        self._patch(curiosity_node, "save_checkpoint", timed_save)

    def _patch(self, owner, name: str, value) -> None:
        self._undo.append((owner, name, getattr(owner, name)))
        setattr(owner, name, value)

    def restore(self) -> None:
        for owner, name, original in reversed(self._undo):
            setattr(owner, name, original)
        self._undo.clear()


def _blocks(values: list, size: int) -> list[list]:
    return [values[i:i + size] for i in range(0, len(values), size)]


def _median(values: list[float], digits: int = 4) -> float | None:
    return round(statistics.median(values), digits) if values else None


def run() -> dict:
    meter = Meter(keep_events=False)  # a list of every physics step would grow the RSS
    writes = Writes(meter)
    writes.install()
    rss_start = rss_mib()
    try:
        # the run goes on once everything is known: the soak measures the loop, not the
        # learning, and a run that ends at all_known_at is too short to be one
        records, summary, wall = demo_run(
            meter, EXPERIMENTS, {"curiosity_node": {"stop_when_all_known": False}})
    finally:
        writes.restore()
    times = [r["wall_time"] for r in records]
    gaps = [b - a for a, b in zip(times, times[1:], strict=False)]
    floors = [b - a for a, b in zip(writes.work_s, writes.work_s[1:], strict=False)]
    per_block = []
    for k, (gap, floor, app, save, rss) in enumerate(zip(
            _blocks(gaps, BLOCK), _blocks(floors, BLOCK), _blocks(writes.appends, BLOCK),
            _blocks(writes.saves, BLOCK), _blocks(writes.rss, BLOCK), strict=False)):
        per_block.append({
            "experiments": f"{k * BLOCK}-{k * BLOCK + len(app) - 1}",
            "s_per_experiment": _median(gap),
            "floor_s": _median(floor),
            "overhead_ratio": round(_median(gap) / _median(floor), 3),
            "rss_mib_at_end": round(rss[-1], 1),
            "log_append_ms": _median([s * 1e3 for s, _ in app], 3),
            "log_append_bytes": _median([float(b) for _, b in app], 1),
            "checkpoint_save_ms": _median([s * 1e3 for s, _ in save], 3),
            "checkpoint_bytes": _median([float(b) for _, b in save], 1),
        })
    first, last = per_block[0], per_block[-1]

    def ratio(key: str) -> float | None:
        a, b = first[key], last[key]
        return round(b / a, 3) if a and b is not None else None

    return {
        "experiments": len(records),
        "block": BLOCK,
        "per_block": per_block,
        "last_over_first_s_per_experiment": ratio("s_per_experiment"),
        "last_over_first_floor": ratio("floor_s"),
        "last_over_first_overhead_ratio": ratio("overhead_ratio"),
        "last_over_first_log_append": ratio("log_append_ms"),
        "last_over_first_checkpoint_save": ratio("checkpoint_save_ms"),
        "rss_mib_before_run": round(rss_start, 1),
        "rss_growth_mib": round(last["rss_mib_at_end"] - first["rss_mib_at_end"], 1),
        "dropped_experiments": summary.get("dropped_experiments", {}),
        "all_known_at": summary.get("all_known_at"),
        "run_wall_s": round(wall, 1),
        "targets": TARGETS,
        "notes": (f"katana-demo --experiments {EXPERIMENTS} --seed 0 --params OVERLAY "
                  "(curiosity_node: stop_when_all_known false) in this process (sim at "
                  "real_time_factor 0, every node in one process, headless); per block of "
                  f"{BLOCK}: the median gap between logged experiments beside the median "
                  "time inside physics, renders, segmentation, the judge and the fovea "
                  "between them (floor_s), the process's RSS "
                  "when its last experiment was logged, and the median time and bytes of the "
                  "log's append and the checkpoint's save; rss_growth_mib is the last "
                  "block's RSS less the first's (the first block is the floor of the last)."),
    }


if __name__ == "__main__":
    print(json.dumps(run(), indent=2))
