"""The curiosity loop against the Katana EMULATOR in real time (time scale 1), as a user runs it
(docs/hardware.md section 3): seconds per experiment, the arm's motion in each experiment, and
the least motion time the arm's speed and acceleration limits allow on the same paths.

`katana-run --backend hardware` runs as a subprocess against the emulator with the shipped
YAML (only the emulator's address and the substitute camera overridden). The emulator answers
every request LINK_LATENCY_S late, as the real arm does (docs/KATANA.md): the goals' starts,
the polls that see a motion end and the streaming cost what they cost on the arm. It has no
blocks: its gripper stalls where a 4 cm block would hold the fingers, so grasps read as
holding one. Every spline segment the emulator accepts is recorded; an experiment's motion is
the sum of its arm segments' durations, and its least time is core.time_optimal's on the
knots the driver sent, each rest-to-rest move on its own (a move ends where every arm joint is
at rest). The floor of the loop is that motion: the target is at most motion + 1 s.

Every 10 ms tick in which a motor moved is recorded too: `finger_motion_s` is the time the
fingers moved in an experiment (the arm stands meanwhile: motor 6 holds in every spline row),
`still_s` the time no motor moved, and `still_by_step_s` splits the still time by where it
falls: between two arm goals, between an arm goal and a finger move (either way), and around
the logging of an experiment (from the park's end to the next experiment's first motion).
"""

from __future__ import annotations

import json
import math
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
from katana_common.testing import private_ros_env
from katana_description import models
from katana_driver.core.encoders import EncoderModel
from katana_driver.core.protocol import TICK_S
from katana_emulator.emulator import Faults, KatanaEmulator, KatanaModel
from katana_manipulation.core.kinematics import MAX_ACCEL, MAX_SPEED
from katana_manipulation.core.time_optimal import minimum_time

EXPERIMENTS = 11  # 10 gaps between consecutive logged experiments
#: a request takes about 40 ms on the real arm (docs/KATANA.md): the emulator answers this late
LINK_LATENCY_S = 0.04
STILL_MIN_TICKS = 3  # still stretches shorter than this are the ticks between two segments
TIMEOUT_S = 1800.0
TARGETS = {"overhead_s": 1.0, "motion_over_min": 1.5}  # overhead: s_per_experiment - motion
ARM_MOTORS = 5
REST_ENC_PER_TICK = 0.05  # an end slope below this is at rest


def start_emulator(recorded: list, moved: list | None = None):
    """The emulator, in real time, answering every request LINK_LATENCY_S late, serving on a
    free loopback port with a 4 cm block in the gripper (as `katana-emulator --latency 0.04
    --block-width-m 0.04`); every spline segment it accepts is appended to ``recorded`` as
    (wall time, motor index, segment), and (wall time, motor index) of every motor that moved
    in a 10 ms tick to ``moved``. In process: the recording wraps the model's segment check
    and its motor step."""
    model = KatanaModel(variant="6M180", time_scale=1.0, block_width_m=models.BLOCK_SIZE[0])
    check = model._check_spline
    step = model._step
    wall_minus_mono = time.time() - time.monotonic()

    def recording(m, seg, queued):
        check(m, seg, queued)
        recorded.append((time.time(), m.index, seg))

    def stepping(m, tick):
        before = m.pos
        step(m, tick)
        if moved is not None and m.pos != before:
            moved.append((wall_minus_mono + model._t0 + tick * TICK_S / model.time_scale,
                          m.index))

    model._check_spline = recording
    model._step = stepping
    emu = KatanaEmulator(model, Faults(latency_s=LINK_LATENCY_S))
    emu.serve_tcp("127.0.0.1", 0)
    return emu, emu.address


def still_steps(moved: list, a: float, b: float) -> tuple[float, float, dict[str, float]]:
    """Over the wall-time window (a, b]: seconds the fingers moved, seconds no motor moved,
    and those still seconds by where they fall ('arm -> arm', 'arm -> fingers', 'fingers ->
    arm', 'fingers -> fingers', 'around the log': before the window's first motion and after
    its last)."""
    first, last = int(math.floor(a / TICK_S)) + 1, int(math.floor(b / TICK_S))
    kind: dict[int, str] = {}
    for t, motor in moved:
        tick = int(math.floor(t / TICK_S))
        if first <= tick <= last:
            kind[tick] = "arm" if motor <= ARM_MOTORS or kind.get(tick) == "arm" else "fingers"
    fingers = TICK_S * sum(1 for k in kind.values() if k == "fingers")
    still = b - a - TICK_S * len(kind)
    steps: dict[str, float] = defaultdict(float)
    previous, run = None, 0
    for tick in range(first, last + 1):
        if tick not in kind:
            run += 1
            continue
        if run:
            label = ("around the log" if previous is None else f"{previous} -> {kind[tick]}")
            if previous is None or run >= STILL_MIN_TICKS:
                steps[label] += run * TICK_S
            run = 0
        previous = kind[tick]
    steps["around the log"] += run * TICK_S
    return fingers, still, dict(steps)


def _rows(recorded: list) -> list[tuple[float, list]]:
    """The arm's segment rows (motors 1..5 in order), with the wall time of each."""
    rows, row = [], {}
    for t, motor, seg in recorded:
        if motor > ARM_MOTORS:
            continue
        row[motor] = seg
        if motor == ARM_MOTORS and len(row) == ARM_MOTORS:
            segs = [row[k] for k in range(1, ARM_MOTORS + 1)]
            if not all(s.p1 == s.p2 == s.p3 == 0 and s.p0 == s.target for s in segs):
                rows.append((t, segs))
            row = {}
    return rows


def _moves(rows: list) -> list[tuple[float, float, np.ndarray]]:
    """Rest-to-rest moves: (wall time sent, seconds, knots in rad (start first))."""
    enc = EncoderModel()
    moves, knots, seconds, t0 = [], None, 0.0, 0.0
    for t, segs in rows:
        if knots is None:
            knots = [[enc.encoder_to_angle(k + 1, s.coefficients()[0]) for k, s in enumerate(segs)]]
            seconds, t0 = 0.0, t
        knots.append([enc.encoder_to_angle(k + 1, float(s.target)) for k, s in enumerate(segs)])
        seconds += segs[0].duration * TICK_S
        end_speed = []
        for s in segs:
            _, c1, c2, c3 = s.coefficients()
            end_speed.append(abs(c1 + 2 * c2 * s.duration + 3 * c3 * s.duration**2))
        if max(end_speed) < REST_ENC_PER_TICK:
            moves.append((t0, seconds, np.array(knots)))
            knots = None
    return moves


def run() -> dict:
    recorded: list = []
    moved: list = []
    emu, (host, port) = start_emulator(recorded, moved)
    tmp = Path(tempfile.mkdtemp(prefix="bench_loop_hardware_"))
    overlay = tmp / "emulator.yaml"
    overlay.write_text(
        "katana_driver_node:\n  ros__parameters:\n"
        f"    host: \"{host}\"\n    port: {port}\n"
        "camera_node:\n  ros__parameters:\n    device: \"substitute\"\n")
    (tmp / "run").mkdir()
    log = tmp / "run" / "katana-run.log"
    experiences = tmp / "run" / "runs" / "robot" / "experience.jsonl"
    with open(log, "w") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "katana_bringup.run", "--backend", "hardware",
             "--params", str(overlay)], cwd=tmp / "run", env=private_ros_env(), stdout=out,
            stderr=subprocess.STDOUT)
    deadline = time.monotonic() + TIMEOUT_S
    try:
        while True:
            if proc.poll() is not None:
                raise RuntimeError("katana-run stopped:\n" + log.read_text()[-3000:])
            if time.monotonic() > deadline:
                raise RuntimeError(f"fewer than {EXPERIMENTS} experiments in {TIMEOUT_S} s")
            if experiences.exists() and experiences.read_text().count("\n") >= EXPERIMENTS:
                break
            time.sleep(1.0)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
        stopper = threading.Thread(target=emu.stop, daemon=True)
        stopper.start()
        stopper.join(10)
    records = [json.loads(line) for line in experiences.read_text().splitlines()][:EXPERIMENTS]
    walls = [r["wall_time"] for r in records]
    moves = _moves(_rows(recorded))
    motion, least, fingers, still, steps = [], [], [], [], []
    for a, b in zip(walls[:-1], walls[1:], strict=True):  # the moves logged with experiment b
        inside = [mv for mv in moves if a < mv[0] <= b]
        motion.append(sum(mv[1] for mv in inside))
        least.append(sum(minimum_time(mv[2], MAX_SPEED, MAX_ACCEL) for mv in inside))
        f, s, by_step = still_steps(moved, a, b)
        fingers.append(f)
        still.append(s)
        steps.append(by_step)
    gaps = [b - a for a, b in zip(walls[:-1], walls[1:], strict=True)]
    stages = {k: statistics.median(r["stage_s"][k] for r in records if k in r["stage_s"])
              for k in sorted({k for r in records for k in r["stage_s"]})}
    ratios = [m / lo for m, lo in zip(motion, least, strict=True) if lo > 0]
    s_per = statistics.median(gaps)
    motion_s = statistics.median(motion)
    labels = sorted({k for by_step in steps for k in by_step})
    return {
        "experiments": len(gaps),
        "time_scale": 1.0,
        "link_latency_s": LINK_LATENCY_S,
        "s_per_experiment": round(s_per, 3),
        "motion_s": round(motion_s, 3),
        "motion_min_s": round(statistics.median(least), 3),
        "motion_over_min": round(statistics.median(ratios), 3) if ratios else None,
        "observe_s": round(stages.get("observe_s", float("nan")), 3),
        "pick_place_s": round(stages.get("pick_place_s", float("nan")), 3),
        "stage_median_s": {k: round(v, 3) for k, v in stages.items()},
        "floor_s": round(motion_s, 3),
        "overhead_s": round(s_per - motion_s, 3),
        "moves_per_experiment": round(len(moves) / max(len(gaps), 1), 2),
        # the fingers move while the arm stands (motor 6 holds in every spline row)
        "finger_motion_s": round(statistics.median(fingers), 3),
        # per experiment: the time no motor moved, and where it fell (medians)
        "still_s": round(statistics.median(still), 3),
        "still_by_step_s": {k: round(statistics.median(by.get(k, 0.0) for by in steps), 3)
                            for k in labels},
        "targets": TARGETS,
    }


if __name__ == "__main__":
    print(json.dumps(run(), indent=2))
