"""The whole loop on the simulated arm: seconds per experiment, its stages, and its floor.

Runs `katana-demo` in this process (every node in one process, headless, real_time_factor 0,
seed 0) for EXPERIMENTS experiments. The stage times are what the curiosity node logs with
each experiment. The floor is measured on the same experiments: the time spent inside the
work the loop runs on - physics steps (`PhysicsSim.step` and its free-space check `free_run`:
the motions and the settling of the blocks), camera renders (`PhysicsSim.render`),
segmentation (`Segmenter.segment`), the judge (`Judge.snapshot` / `Judge.judge`) and the fovea
(`FoveaScene` construction, `observe`, `find`) - summed per experiment window (from one
logged experiment to the next). The ratio s_per_experiment / experiment_floor_s is the loop's
overhead: waits, polling, ROS transport. Renders beyond the two images an experiment needs are
shown apart (experiment_floor_two_images_s): they are work, but work nobody uses.
"""

from __future__ import annotations

import bisect
import json
import os
import statistics
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path

import yaml
from katana_bringup import demo
from katana_bringup.run import default_params_files, load_params
from katana_perception.core.fovea import FoveaScene
from katana_perception.core.judge import Judge
from katana_perception.core.segmentation import Segmenter
from katana_sim.core.physics import PhysicsSim

# the graph runs in this process: it discovers nothing outside it, so that another graph on
# the machine (a second bench, a demo) cannot answer its topics and services
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")

EXPERIMENTS = 31  # 30 gaps between consecutive logged experiments
TARGETS = {"s_per_experiment": 1.0, "overhead_ratio": 1.3, "dropped_fraction": 0.1}


class Meter:
    """Wraps methods to record (wall end time, seconds, kind) of their outermost calls; with
    keep_events False only the running seconds per kind (`totals`), in memory that does not
    grow with the run."""

    def __init__(self, keep_events: bool = True) -> None:
        self.keep_events = keep_events
        self.events: list[tuple[float, float, str]] = []
        self.totals: dict[str, float] = defaultdict(float)
        self._local = threading.local()
        self._lock = threading.Lock()
        self._undo: list[tuple[type, str, object]] = []
        self.worlds: list[PhysicsSim] = []  # every world made while the meter is on

    def wrap(self, cls: type, name: str, kind: str) -> None:
        original = getattr(cls, name)
        meter = self

        def timed(*args, **kwargs):
            depth = getattr(meter._local, "depth", 0)
            meter._local.depth = depth + 1
            start = time.perf_counter()
            try:
                return original(*args, **kwargs)
            finally:
                meter._local.depth = depth
                if depth == 0:
                    seconds = time.perf_counter() - start
                    with meter._lock:
                        meter.totals[kind] += seconds
                        if meter.keep_events:
                            meter.events.append((time.time(), seconds, kind))

        setattr(cls, name, timed)
        self._undo.append((cls, name, original))

    def track_worlds(self) -> None:
        """Keep every PhysicsSim made from now on (their step counters)."""
        original = PhysicsSim.__init__
        meter = self

        def init(world, *args, **kwargs):
            original(world, *args, **kwargs)
            meter.worlds.append(world)

        PhysicsSim.__init__ = init
        self._undo.append((PhysicsSim, "__init__", original))

    def restore(self) -> None:
        for cls, name, original in reversed(self._undo):
            setattr(cls, name, original)
        self._undo.clear()


def _instrument(meter: Meter) -> None:
    meter.track_worlds()
    meter.wrap(PhysicsSim, "step", "physics")
    meter.wrap(PhysicsSim, "free_run", "physics")  # the free-space check ahead of a step
    meter.wrap(PhysicsSim, "_raw_render", "render")  # images drawn (a still scene's are not)
    meter.wrap(Segmenter, "segment", "segment")
    meter.wrap(Judge, "snapshot", "judge")
    meter.wrap(Judge, "judge", "judge")
    meter.wrap(FoveaScene, "__init__", "fovea")
    meter.wrap(FoveaScene, "observe", "fovea")
    meter.wrap(FoveaScene, "find", "fovea")


def _median(values: list[float]) -> float | None:
    return round(statistics.median(values), 4) if values else None


KINDS = ("physics", "render", "segment", "judge", "fovea")


def demo_run(meter: Meter, experiments: int = EXPERIMENTS,
             params: dict[str, dict] | None = None) -> tuple[list[dict], dict, float]:
    """katana-demo (seed 0) in this process with `meter` on: the logged records, the summary,
    wall s. `params` ({node: {name: value}}) is handed over as a `--params` overlay file (a
    `--ros-args -p` value would lose to the packaged files, as rclpy ranks them)."""
    _instrument(meter)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "run"
            overlay = []
            if params:
                path = Path(tmp) / "overlay.yaml"
                path.write_text(yaml.safe_dump(
                    {node: {"ros__parameters": values} for node, values in params.items()}))
                overlay = ["--params", str(path)]
            start = time.perf_counter()
            code = demo.main(["--experiments", str(experiments), "--out", str(out),
                              "--seed", "0", "--timeout", str(60 * experiments), *overlay])
            wall = time.perf_counter() - start
            if code != 0:
                raise RuntimeError(f"katana-demo exited with {code}")
            lines = (out / "experience.jsonl").read_text().splitlines()
            records = [json.loads(line) for line in lines]
            summary = json.loads((out / "summary.json").read_text())
    finally:
        meter.restore()
    return records, summary, wall


def windows(times: list[float], events: list[tuple[float, float, str]]):
    """Per window (previous experiment logged, this one logged]: the seconds of each kind of
    work, and the renders and segmentations in it."""
    events = sorted(events)
    ends = [end for end, _, _ in events]
    floors: list[dict[str, float]] = []
    renders: list[int] = []
    segments: list[int] = []
    for a, b in zip(times, times[1:], strict=False):
        inside = events[bisect.bisect_right(ends, a):bisect.bisect_right(ends, b)]
        sums: dict[str, float] = defaultdict(float)
        for _, seconds, kind in inside:
            sums[kind] += seconds
        floors.append(dict(sums))
        renders.append(sum(1 for _, _, kind in inside if kind == "render"))
        segments.append(sum(1 for _, _, kind in inside if kind == "segment"))
    return floors, renders, segments


def _two_images(floors: list[dict], renders: list[int], segments: list[int]) -> list[float]:
    """The floor with only the two images an experiment needs (after parking, for the judge;
    after the experience, for the memory): the cost of the images nobody needed."""
    return [
        f.get("physics", 0.0) + f.get("fovea", 0.0) + f.get("judge", 0.0)
        + f.get("render", 0.0) * min(1.0, 2.0 / max(n, 1))
        + f.get("segment", 0.0) * min(1.0, 2.0 / max(k, 1))
        for f, n, k in zip(floors, renders, segments, strict=True)]


NOTES = (f"katana-demo --experiments {EXPERIMENTS} --seed 0 in this process (sim at "
         "real_time_factor 0, every node in one process, headless); s_per_experiment "
         "is the median wall time between consecutive logged experiments (dropped "
         "attempts included); stage figures are medians of what the curiosity node "
         "logged; experiment_floor_s is the median per window of the time inside "
         "physics steps, renders, segmentation, the judge and the fovea; "
         "experiment_floor_two_images_s counts only the two camera images an "
         "experiment needs (renders and segmentation scaled to 2 per window).")


def run() -> dict:
    camera_rate_hz = load_params(default_params_files("sim"))["sim_node"]["camera_rate"]
    meter = Meter()
    records, summary, wall = demo_run(meter)
    times = [r["wall_time"] for r in records]
    gaps = [b - a for a, b in zip(times, times[1:], strict=False)]
    floors, renders, segments = windows(times, meter.events)

    def stage(name: str) -> list[float]:
        return [r["stage_s"][name] for r in records[1:] if name in r.get("stage_s", {})]

    stage_names = sorted({k for r in records for k in r.get("stage_s", {})})
    s_per = _median(gaps)
    floor = _median([sum(f.values()) for f in floors])
    return {
        "experiments": len(records),
        "s_per_experiment": s_per,
        "s_per_experiment_mean": round(statistics.mean(gaps), 4) if gaps else None,
        "stage_median_s": {k: _median(stage(k)) for k in stage_names},
        "between_experiments_s": _median([g - r["stage_s"].get("experiment_s", 0.0)
                                          for g, r in zip(gaps, records[1:], strict=True)]),
        "experiment_floor_s": floor,
        "experiment_floor_two_images_s": _median(_two_images(floors, renders, segments)),
        "floor_median_s": {k: _median([f.get(k, 0.0) for f in floors]) for k in KINDS},
        "overhead_ratio": round(s_per / floor, 2) if s_per and floor else None,
        # over the whole run (its start-up included): steps made by the physics engine, and
        # steps the arm made along its plan through free space without it
        "physics_steps_per_experiment": round(
            sum(w.physics_steps for w in meter.worlds) / len(records), 1),
        "kinematic_steps_per_experiment": round(
            sum(w.kinematic_steps for w in meter.worlds) / len(records), 1),
        "renders_per_experiment": _median([float(n) for n in renders]),
        "segmentations_per_experiment": _median([float(n) for n in segments]),
        "camera_rate_hz": camera_rate_hz,
        "dropped_experiments": summary.get("dropped_experiments", {}),
        "highest_stack": summary["highest_stack"],
        "heights_explored": summary["heights_explored"],
        "run_wall_s": round(wall, 1),
        "targets": TARGETS,
        "notes": NOTES,
    }


if __name__ == "__main__":
    print(json.dumps(run(), indent=2))
