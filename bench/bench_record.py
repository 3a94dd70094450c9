"""What recording costs the fast-sim loop: seconds per experiment with `--record` beside the
same loop without it (the floor), and the time spent inside the recorder's writes and flushes.

Runs `katana-demo` in this process (as bench_loop: every node in one process, headless,
real_time_factor 0, seed 0) RUNS times alternately without and with `--record FILE.mcap`, so
that both see the same load drift of a shared machine. s_per_experiment of each is the median
of the gaps between consecutive logged experiments over its runs; overhead = with / without -
1 (target: under 5 %). The direct cost, record_s_per_experiment, is the time inside
`McapRecording.write` and `McapRecording.flush` per experiment (serializing is rmw's, on
receipt, and not in it): it does not depend on the noise between runs.
"""

from __future__ import annotations

import json
import statistics
import tempfile
import threading
import time
from pathlib import Path

from katana_bringup import demo
from katana_bringup.recording import McapRecording, read_recording

EXPERIMENTS = 16  # 15 gaps per run
RUNS = 4  # without, with, without, with
TARGETS = {"overhead_fraction": 0.05}


class _Timer:
    """Wall seconds inside the wrapped methods, from every thread."""

    def __init__(self) -> None:
        self.seconds = 0.0
        self.calls = 0
        self._lock = threading.Lock()
        self._undo: list[tuple[str, object]] = []

    def wrap(self, name: str) -> None:
        original = getattr(McapRecording, name)
        timer = self

        def timed(*args, **kwargs):
            start = time.perf_counter()
            try:
                return original(*args, **kwargs)
            finally:
                with timer._lock:
                    timer.seconds += time.perf_counter() - start
                    timer.calls += 1

        setattr(McapRecording, name, timed)
        self._undo.append((name, original))

    def restore(self) -> None:
        for name, original in self._undo:
            setattr(McapRecording, name, original)


def _demo_gaps(record: bool, timer: _Timer) -> tuple[list[float], dict]:
    """One katana-demo run: the gaps between logged experiments, and what the file holds."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        argv = ["--experiments", str(EXPERIMENTS), "--out", str(out), "--seed", "0",
                "--timeout", str(60 * EXPERIMENTS)]
        if record:
            argv += ["--record", str(Path(tmp) / "run.mcap")]
            timer.wrap("write")
            timer.wrap("flush")
        try:
            code = demo.main(argv)
        finally:
            timer.restore()
        if code != 0:
            raise RuntimeError(f"katana-demo exited with {code}")
        times = [json.loads(line)["wall_time"]
                 for line in (out / "experience.jsonl").read_text().splitlines()]
        info: dict = {}
        if record:
            path = Path(tmp) / "run.mcap"
            info = {"file_bytes": path.stat().st_size,
                    "messages": sum(1 for _ in read_recording(path))}
    return [b - a for a, b in zip(times, times[1:], strict=False)], info


def run() -> dict:
    gaps: dict[bool, list[float]] = {False: [], True: []}
    timer = _Timer()
    files = []
    for i in range(RUNS):
        record = i % 2 == 1
        run_gaps, info = _demo_gaps(record, timer)
        gaps[record] += run_gaps
        if info:
            files.append(info)
    without = statistics.median(gaps[False])
    with_rec = statistics.median(gaps[True])
    experiments = len(gaps[True])
    record_s = timer.seconds / experiments if experiments else None
    return {
        "experiments_per_run": EXPERIMENTS,
        "runs": RUNS,
        "s_per_experiment_without_recording": round(without, 4),
        "s_per_experiment_with_recording": round(with_rec, 4),
        "overhead_fraction": round(with_rec / without - 1.0, 4),
        "record_s_per_experiment": round(record_s, 5) if record_s is not None else None,
        "record_fraction_of_experiment": round(record_s / with_rec, 4) if record_s else None,
        "recorder_calls": timer.calls,
        "recorded_messages_per_run": [f["messages"] for f in files],
        "recorded_mib_per_run": [round(f["file_bytes"] / 2**20, 2) for f in files],
        "targets": TARGETS,
        "notes": (f"katana-demo --experiments {EXPERIMENTS} --seed 0 in this process, {RUNS} "
                  "runs alternately without and with --record (default recorder: images at "
                  "2 Hz, chunks flushed every 1 s); s_per_experiment is the median gap between "
                  "logged experiments over the runs of each kind; the floor is the loop "
                  "without recording; record_s_per_experiment is the time inside "
                  "McapRecording.write and flush per experiment."),
    }


if __name__ == "__main__":
    print(json.dumps(run(), indent=2))
