"""Speed of the perception core: segmentation of one 640x480 frame (beside its floor, the one
colour conversion every segmentation starts with), fovea/observe of a 4-block setting (beside
its reference twin, timed in alternation in the same run, and checked to give the same
instances), one placement judgement, the reach table fovea_node computes once at start-up, and
writing one camera frame into a recording. `run()` returns the figures (milliseconds, median
over repetitions); run as a script it also writes bench/results/perception.json."""

from __future__ import annotations

import json
import statistics
import tempfile
import time
from pathlib import Path

import cv2
from katana_bringup.recording import McapRecording
from katana_manipulation.core import reach
from katana_perception.core.calibration import Calibration
from katana_perception.core.fovea import FoveaScene, FoveaSceneReference
from katana_perception.core.judge import Judge, Placement
from katana_perception.core.memory import Block
from katana_perception.core.segmentation import Segmenter
from katana_perception.core.synthetic import Renderer, stack_block
from katana_perception.messages import rgb_to_image
from rclpy.serialization import serialize_message
from std_msgs.msg import Header


def _median_ms(fn, repeat: int, warmup: int = 3) -> float:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1000.0)
    return statistics.median(times)


def _alternating_median_ms(fns, repeat: int, warmup: int = 3) -> list[float]:
    """Median times of several functions run in turn, so that all see the same machine load
    (their ratio is the figure on a shared, noisy machine)."""
    for _ in range(warmup):
        for fn in fns:
            fn()
    times: list[list[float]] = [[] for _ in fns]
    for _ in range(repeat):
        for fn, out in zip(fns, times, strict=True):
            t0 = time.perf_counter()
            fn()
            out.append((time.perf_counter() - t0) * 1000.0)
    return [statistics.median(t) for t in times]


def _frames():
    """Frames of four blocks before and after red is put on a stack of two, and the memory
    of the before scene: from the PyBullet sim when installed, else the synthetic renderer."""
    try:
        from katana_sim.core import PhysicsSim, SimConfig  # noqa: PLC0415 - optional: PyBullet may be missing
    except ImportError:
        calib = Calibration.overhead_default()
        before = [stack_block("red", 0.17, 0.09, 1, 0.2), stack_block("green", 0.26, -0.1, 1),
                  stack_block("blue", 0.26, -0.1, 2, 0.1), stack_block("yellow", 0.2, 0.0, 1)]
        after = before[1:] + [stack_block("red", 0.263, -0.1, 3, 0.1)]
        r = Renderer(calib)
        memory = [Block(b.name, b.name, b.x, b.y, b.yaw, level=b.level,
                        support="green" if b.name == "blue" else None) for b in before]
        return "synthetic", calib, r.render(before)[0], r.render(after)[0], memory
    world = PhysicsSim(SimConfig(num_blocks=4, seed=1))
    try:
        cam = world.camera
        calib = Calibration.from_camera_rpy(cam.K, cam.position, cam.rpy, cam.width, cam.height)
        world.stack("blue", on="green")
        world.settle()
        memory = [Block(b.id, b.id, b.position[0], b.position[1], b.yaw, level=b.level,
                        support=b.support or None) for b in world.ground_truth()]
        before = world.render()
        world.stack("red", on="blue", dx=0.003)
        world.settle()
        return "pybullet", calib, before, world.render(), memory
    finally:
        world.close()


def _reach_table_ms() -> float:
    """place_reach for heights 0..3 from the kinematics, uncached: fovea_node's start-up cost."""
    def once() -> None:
        reach.place_reach.cache_clear()
        reach.place_reach_table(3)

    return _median_ms(once, repeat=3, warmup=1)


def _record_frame_ms(rgb) -> float:
    """One 640x480 camera frame serialized and written into an MCAP recording, its chunk then
    closed (zstd-compressed, indexed and handed to the OS), as the recorder's flush does."""
    msg = rgb_to_image(rgb, Header(frame_id="camera_optical_frame"))
    with tempfile.TemporaryDirectory() as folder:
        rec = McapRecording(Path(folder) / "bench.mcap")
        rec.add_topic("/camera/image_raw", "sensor_msgs/msg/Image")
        t = iter(range(10**9))

        def once() -> None:
            rec.write("/camera/image_raw", serialize_message(msg), next(t))
            rec.flush()

        ms = _median_ms(once, repeat=50)
        rec.close()
    return ms


def run() -> dict:
    source, calib, before_rgb, after_rgb, blocks = _frames()
    seg = Segmenter()
    levels = {b.id: b.level for b in blocks}
    perception_ms = _median_ms(lambda: seg.segment(before_rgb, calib, levels), repeat=200)
    eight = Renderer(calib).render(
        [stack_block(n, x, y, 1, 0.3 * i) for i, (n, x, y) in enumerate(
            [("red", 0.16, 0.1), ("green", 0.28, 0.1), ("blue", 0.16, -0.1),
             ("yellow", 0.28, -0.1), ("orange", 0.22, 0.0), ("purple", 0.22, 0.13),
             ("cyan", 0.22, -0.13), ("magenta", 0.16, 0.0)])])[0]
    perception_8_ms = _median_ms(lambda: seg.segment(eight, calib), repeat=200)

    instances = FoveaScene(blocks, calib).observe()  # the first call compiles (cached on disk)
    identical = instances == FoveaSceneReference(blocks, calib).observe()
    observe_ms, observe_reference_ms = _alternating_median_ms(
        [lambda: FoveaScene(blocks, calib).observe(),
         lambda: FoveaSceneReference(blocks, calib).observe()], repeat=20)

    judge = Judge(seg, calib)
    top = next(b for b in blocks if b.id == "blue")
    placement = Placement(2, top.x + 0.003, top.y, ("green", "blue"))

    def judge_once() -> int:
        return judge.judge(judge.snapshot(before_rgb, blocks), after_rgb, "red", placement).label

    label = judge_once()
    judge_ms = _median_ms(judge_once, repeat=50)
    floor_ms = _median_ms(lambda: cv2.cvtColor(before_rgb, cv2.COLOR_RGB2HSV), repeat=200)
    return {
        "perception_ms": round(perception_ms, 3),
        "perception_target_ms": 10.0,
        "perception_floor_ms": round(floor_ms, 3),
        "perception_8_blocks_ms": round(perception_8_ms, 3),
        "observe_ms": round(observe_ms, 3),
        "observe_reference_ms": round(observe_reference_ms, 3),
        "observe_target_ms": 10.0,
        "observe_instances": len(instances),
        "observe_identical_to_reference": bool(identical),
        "judge_ms": round(judge_ms, 3),
        "judge_label": int(label),
        "reach_table_ms": round(_reach_table_ms(), 1),
        "record_frame_ms": round(_record_frame_ms(before_rgb), 3),
        "frames": source,
        "image": f"{before_rgb.shape[1]}x{before_rgb.shape[0]}",
    }


if __name__ == "__main__":
    from run import machine  # noqa: PLC0415 - bench/run.py, beside this script

    result = {"bench": "perception", "machine": machine(), **run()}
    out = Path(__file__).resolve().parent / "results" / "perception.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
