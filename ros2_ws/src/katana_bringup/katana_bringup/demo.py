"""katana-demo: the paper's robot experiment (sections 2 and 3.3) on the simulated Katana.

    katana-demo [--experiments 200] [--out DIR] [--strategy q1] [--seed 0] [--backend sim]

Starts the whole node graph in one process (sim or hardware, executor, perception, memory,
fovea, curiosity), headless, and lets the curiosity node run a bounded number of experiments
into a run folder. The curiosity node reports every experiment on the terminal (number, query
or plan, height, label, experiments per minute). At the end the folder holds the experience
log, the learner checkpoint, summary.json, model.png (learned stability model per height and
action with its confidence band, cf. the paper's Figure 13), experience.png (direct and
planned experience per height, cf. Figure 4) and frames/ (camera images before and after a
few placements, with the fovea and the chosen placement drawn).
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from datetime import datetime
from pathlib import Path

import cv2
import numpy as np
from katana_common.cli_args import (
    non_negative_int,
    positive_int,
    positive_seconds,
    writable_folder,
)
from katana_description.models import lies_flat

from .run import (
    EXECUTOR_THREADS,
    KATANA_RUN_SHUTDOWN_LIMIT_S,
    add_graph_arguments,
    build_nodes,
    default_params_files,
    load_params,
)

FRAMES_FIRST = 6  # frames of the first experiments, then one every FRAMES_EVERY
FRAMES_EVERY = 25


def draw_placement(rgb: np.ndarray, u: float, v: float, bits, text: str, fovea_px: int = 40,
                   offset_px: float = 10.0, stable: bool | None = None) -> np.ndarray:
    """The fovea window, its five test points (filled: inside the hull) and a caption."""
    bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    colour = (0, 200, 255) if stable is None else ((0, 200, 0) if stable else (0, 0, 230))
    half = fovea_px / 2
    cv2.rectangle(bgr, (round(u - half), round(v - half)), (round(u + half), round(v + half)),
                  colour, 1)
    points = [(0, 0), (offset_px, offset_px), (-offset_px, offset_px), (-offset_px, -offset_px),
              (offset_px, -offset_px)]
    for (du, dv), on in zip(points, list(bits) + [False] * (5 - len(bits)), strict=False):
        cv2.circle(bgr, (round(u + du), round(v + dv)), 3, colour, -1 if on else 1)
    cv2.putText(bgr, text, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, colour, 2, cv2.LINE_AA)
    return bgr


class FrameRecorder:
    """Keeps the camera frame before and after each experiment and saves a few of them."""

    def __init__(self, node, out: Path, ground_truth: bool = False) -> None:
        from katana_interfaces.msg import BlockArray, Experience
        from katana_perception.conversions import image_to_rgb
        from rclpy.qos import qos_profile_sensor_data
        from sensor_msgs.msg import Image

        self.out = out
        self.out.mkdir(parents=True, exist_ok=True)
        self._to_rgb = image_to_rgb
        self._latest: np.ndarray | None = None
        self._before: np.ndarray | None = None
        self._lock = threading.Lock()
        self.saved: list[Path] = []
        self.truth = None
        self.agreement: list[bool] = []  # judge's label vs the sim's ground truth, per experiment
        node.create_subscription(Image, "camera/image_raw", self._on_image,
                                 qos_profile_sensor_data)
        node.create_subscription(Experience, "curiosity/experience", self._on_experience, 10)
        if ground_truth:  # evaluation only: the learner never sees it
            from rclpy.qos import DurabilityPolicy, QoSProfile

            node.create_subscription(
                BlockArray, "sim/ground_truth", self._on_truth,
                QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))

    def _on_truth(self, msg) -> None:
        self.truth = msg

    def _truly_stable(self, msg) -> bool | None:
        """Does the sim agree the placed block rests on the stack, at the placement?"""
        if self.truth is None:
            return None
        block = next((b for b in self.truth.blocks if b.id == msg.moved_block), None)
        if block is None:
            return None
        place = msg.instance.placement.position
        near = np.hypot(block.pose.position.x - place.x, block.pose.position.y - place.y) < 0.015
        q = block.pose.orientation
        return bool(near and lies_flat(q.x, q.y, q.z, q.w)
                    and block.level == msg.instance.state + 1)

    def _on_image(self, msg) -> None:
        try:
            rgb = self._to_rgb(msg)
        except ValueError:
            return
        with self._lock:
            self._latest = rgb
            if self._before is None:
                self._before = rgb

    def _on_experience(self, msg) -> None:
        with self._lock:
            before, after = self._before, self._latest
            self._before = after  # the scene after this experiment is the next one's before
        truth = self._truly_stable(msg)
        agrees = truth is None or truth == (msg.label > 0)
        if truth is not None:
            self.agreement.append(agrees)
        if before is None or after is None:
            return
        interesting = msg.index < FRAMES_FIRST or msg.index % FRAMES_EVERY == 0
        if agrees and not interesting:
            return
        inst = msg.instance
        caption = f"#{msg.index} {msg.mode} s={inst.state} a={inst.action}"
        left = draw_placement(before, inst.pixel_u, inst.pixel_v, inst.bits,
                              caption + " (before)")
        right = draw_placement(after, inst.pixel_u, inst.pixel_v, inst.bits,
                               f"label {msg.label:+d} (after)", stable=msg.label > 0)
        suffix = "" if agrees else "_judge_disagrees_with_sim"
        path = self.out / f"experiment_{msg.index:04d}{suffix}.png"
        cv2.imwrite(str(path), np.hstack([left, right]))
        self.saved.append(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="katana-demo", description=__doc__.split("\n\n")[0])
    parser.add_argument("--experiments", type=positive_int, default=200,
                        help="experiments to run")
    parser.add_argument("--out", type=writable_folder, default=None,
                        help="run folder (default runs/demo-<time>; an existing one resumes)")
    parser.add_argument("--strategy", default=None, help="q1 (default), q10, conf or random")
    parser.add_argument("--seed", type=non_negative_int, default=0,
                        help="seed of the sim and the learner")
    add_graph_arguments(parser)  # --backend, --params (overlays), --record
    parser.add_argument("--real-time-factor", type=float, default=0.0,
                        help="sim pace: 0 as fast as possible (default), 1 wall-clock")
    parser.add_argument("--timeout", type=positive_seconds, default=None, metavar="S",
                        help="give up after S wall seconds (default: 30 s per experiment)")
    args, ros_args = parser.parse_known_args(sys.argv[1:] if argv is None else argv)
    if args.real_time_factor < 0:
        parser.error("--real-time-factor must be >= 0")
    out = args.out or Path("runs") / f"demo-{datetime.now():%Y%m%d-%H%M%S}"
    out.mkdir(parents=True, exist_ok=True)

    params = load_params([*default_params_files(args.backend), *args.params])
    curiosity = params.setdefault("curiosity_node", {})
    curiosity.update(run_dir=str(out), max_experiments=args.experiments, seed=args.seed)
    if args.strategy:
        curiosity["strategy"] = args.strategy
    if not args.params:
        # Headless: nobody looks at the debug image (its drawing would take the shared
        # process's CPU from the physics).
        params.setdefault("perception_node", {})["publish_debug_image"] = False
    if args.backend == "sim":
        params.setdefault("sim_node", {}).update(seed=args.seed,
                                                 real_time_factor=args.real_time_factor)

    import rclpy
    from katana_common.executor import MultiThreadedExecutor
    from katana_common.node_runner import spin_nodes
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions

    # katana-demo handles SIGINT/SIGTERM itself (spin_nodes): the nodes stop before the context
    rclpy.init(args=ros_args, signal_handler_options=SignalHandlerOptions.NO)
    try:
        nodes = build_nodes(args.backend, params, record=args.record)
    except Exception as exc:
        print(f"katana-demo: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    recorder_node = Node("demo_frame_recorder")
    recorder = FrameRecorder(recorder_node, out / "frames", ground_truth=args.backend == "sim")
    learner = next(n for n in nodes if n.get_name() == "curiosity_node")
    print(f"katana-demo: backend {args.backend}, {args.experiments} experiments "
          f"(strategy {learner.strategy_name}), run folder {out}", flush=True)
    start = time.monotonic()
    timeout = args.timeout or 30.0 * args.experiments + 60.0
    spin_nodes([*nodes, recorder_node], "katana-demo", duration_s=timeout,
               executor=MultiThreadedExecutor(num_threads=EXECUTOR_THREADS),
               until=learner.finished, limit_s=KATANA_RUN_SHUTDOWN_LIMIT_S)
    finished = learner.finished.is_set()
    if not finished:
        print("katana-demo: stopped before the last experiment; what was recorded is kept",
              file=sys.stderr)
    wall = time.monotonic() - start
    done = learner.experiments

    from katana_bringup.run_report import append_session, read_sessions, write_report

    # this session's figures are kept beside the log, so a resumed run's summary covers all
    append_session(out, {
        "experiments_at_end": done, "wall_s": round(wall, 1),
        "frames": [p.name for p in recorder.saved],
        "judge_checked": len(recorder.agreement), "judge_agreed": int(sum(recorder.agreement)),
        "dropped_by_reason": dict(learner.loop.dropped_total), "resets": learner.loop.resets,
        "completed": bool(finished)})
    sessions = read_sessions(out)
    checked = sum(s.get("judge_checked", 0) for s in sessions)
    agreed = sum(s.get("judge_agreed", 0) for s in sessions)
    summary = write_report(
        out, n_actions=learner.n_actions, max_height=learner.max_height,
        alpha=learner.rule.alpha, theta=learner.rule.theta,
        extra={"backend": args.backend, "strategy": learner.strategy_name, "seed": args.seed,
               "sessions": len(sessions),
               "wall_s": round(sum(s.get("wall_s", 0.0) for s in sessions), 1),
               "frames": [f for s in sessions for f in s.get("frames", [])],
               "judge_agrees_with_sim": round(agreed / checked, 3) if checked else None,
               "resets": sum(s.get("resets", 0) for s in sessions),
               "completed": bool(finished)},
    )
    status = "done" if finished else "stopped early"
    print(f"katana-demo: {status}: {done} experiments in {wall:.0f} s, highest stack "
          f"{summary['highest_stack']}, heights explored {summary['heights_explored']}")
    print(f"katana-demo: results in {out}/ (summary.json, model.png, experience.png, frames/)")
    return 0 if finished else 1


if __name__ == "__main__":
    sys.exit(main())
