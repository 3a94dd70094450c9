"""katana-demo: the paper's robot experiment (sections 2 and 3.3) on the simulated Katana.

    katana-demo [--experiments 200] [--out DIR] [--strategy q1] [--seed 0] [--backend sim]

Starts the whole node graph in one process (sim or hardware, executor, perception, memory,
fovea, curiosity), headless, and lets the curiosity node run a bounded number of experiments
into a run folder. The curiosity node reports every experiment on the terminal (number, query
or plan, height, label, experiments per minute). At the end the folder holds the experience
log, the learner checkpoint, summary.json, model.png (learned stability model per height and
action with its confidence band, cf. the paper's Figure 13), experience.png (direct and
planned experience per height, cf. Figure 4) and frames/ (camera images before and after a
few placements, with the fovea and the chosen placement drawn); with --contact-sheet FILE.png,
the contact sheet of twelve experiments from --contact-first (katana_bringup.contact_sheet).
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
import rclpy
from katana_common.cli_args import (
    CommandLineError,
    from_spec,
    new_file,
    non_negative_int,
    parse_command_line,
    positive_seconds,
    writable_folder,
)
from katana_common.executor import MultiThreadedExecutor
from katana_common.node_runner import EXIT_INVALID_CONFIGURATION, spin_nodes
from katana_common.param_files import ParamSet
from katana_common.qos import EVENT_QOS, STATE_QOS
from katana_curiosity.node_params import PARAMS as CURIOSITY_PARAMS
from katana_description.models import lies_flat
from katana_interfaces.msg import BlockArray, Experience
from katana_sim.sim_params import PARAMS as SIM_PARAMS
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from .contact_sheet import CONTACT_ROWS, ContactSheetRecorder
from .frames import ExperienceFrames, Frames, draw_placement
from .graph_params import LAYERS
from .live_view import foxglove_address
from .run import (
    EXECUTOR_THREADS,
    KATANA_RUN_SHUTDOWN_LIMIT_S,
    add_graph_arguments,
    build_nodes,
    graph_params_check,
    print_foxglove_url,
    split_ros_args,
)
from .run_report import SessionClock, close_killed_session, read_sessions, write_report
from .terminal import RunTerminal, experiment_line

#: the specs of the parameters the options set: an option is checked by its parameter's rule
_CURIOSITY = {p.name: p for p in CURIOSITY_PARAMS}
_SIM = {p.name: p for p in SIM_PARAMS}

#: how long a finished run waits for its last experience to reach the contact sheet (s)
CONTACT_WAIT_S = 5.0
FRAMES_FIRST = 6  # frames of the first experiments, then one every FRAMES_EVERY
FRAMES_EVERY = 25


class FrameRecorder:
    """Saves the camera frames before and after a few experiments (and of every one whose
    label the sim's ground truth contradicts), with the fovea and the placement drawn."""

    def __init__(self, node, out: Path, ground_truth: bool = False) -> None:
        self.out = out
        self.out.mkdir(parents=True, exist_ok=True)
        self.saved: list[Path] = []
        self.truth = None
        self.agreement: list[bool] = []  # judge's label vs the sim's ground truth, per experiment
        self.frames = ExperienceFrames(node, self._on_experiment)
        if ground_truth:  # evaluation only: the learner never sees it
            node.create_subscription(BlockArray, "sim/ground_truth", self._on_truth, STATE_QOS)

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

    def _on_experiment(self, msg, frames: Frames) -> None:
        truth = self._truly_stable(msg)
        agrees = truth is None or truth == (msg.label > 0)
        if truth is not None:
            self.agreement.append(agrees)
        if frames.before is None or frames.after is None:
            return
        interesting = msg.index < FRAMES_FIRST or msg.index % FRAMES_EVERY == 0
        if agrees and not interesting:
            return
        inst = msg.instance
        caption = f"#{msg.index} {msg.mode} s={inst.state} a={inst.action}"
        left = draw_placement(frames.before, inst.pixel_u, inst.pixel_v, inst.bits,
                              caption + " (before)")
        right = draw_placement(frames.after, inst.pixel_u, inst.pixel_v, inst.bits,
                               f"label {msg.label:+d} (after)", stable=msg.label > 0)
        suffix = "" if agrees else "_judge_disagrees_with_sim"
        path = self.out / f"experiment_{msg.index:04d}{suffix}.png"
        cv2.imwrite(str(path), np.hstack([left, right]))
        self.saved.append(path)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="katana-demo", description=__doc__.split("\n\n")[0])
    parser.add_argument("--experiments", type=from_spec(_CURIOSITY["max_experiments"],
                                                        at_least=1),
                        default=200, help="experiments to run")
    parser.add_argument("--out", type=writable_folder, default=None,
                        help="run folder (default runs/demo-<time>; an existing one resumes)")
    parser.add_argument("--strategy", type=from_spec(_CURIOSITY["strategy"]), default=None,
                        help=f"{', '.join(_CURIOSITY['strategy'].choices)} (default: the "
                        "curiosity node's, q1)")
    parser.add_argument("--seed", type=from_spec(_CURIOSITY["seed"]), default=0,
                        help="seed of the sim and the learner")
    add_graph_arguments(parser)  # --backend, --params (overlays), --record, --foxglove
    parser.add_argument("--real-time-factor", type=from_spec(_SIM["real_time_factor"]),
                        default=0.0,
                        help="sim pace: 0 as fast as possible (default), 1 wall-clock")
    parser.add_argument("--quarantine-bad-lines", action="store_true",
                        help="resuming: move bad lines of the experience log to "
                        "experience.jsonl.quarantine (the log as it was kept beside) and go on")
    parser.add_argument("--verbose", action="store_true",
                        help="the nodes' log lines on the terminal (default: in the run "
                        "folder's nodes.log, with a progress bar and one line per experiment "
                        "on the terminal)")
    parser.add_argument("--timeout", type=positive_seconds, default=None, metavar="S",
                        help="give up after S wall seconds (default: 30 s per experiment)")
    parser.add_argument("--contact-sheet", type=new_file(".png"), default=None,
                        metavar="FILE.png",
                        help=f"draw {CONTACT_ROWS} consecutive experiments into FILE.png in the "
                        "paper's four columns (cf. its Figures 10-12)")
    parser.add_argument("--contact-first", type=non_negative_int, default=0, metavar="N",
                        help="the contact sheet's first experiment (default 0)")
    return parser


def demo_options(args, params: ParamSet) -> None:
    """This run's folder, length and seed over the packaged parameters and the overlays (each
    entry named by its option, so that a refusal names the option)."""
    curiosity = "curiosity_node"
    params.set(curiosity, "run_dir", str(args.out), "--out")
    params.set(curiosity, "max_experiments", args.experiments, "--experiments")
    params.set(curiosity, "seed", args.seed, "--seed")
    if args.strategy:
        params.set(curiosity, "strategy", args.strategy, "--strategy")
    if args.quarantine_bad_lines:
        params.set(curiosity, "quarantine_bad_lines", True, "--quarantine-bad-lines")
    chosen = params.sections.get("perception_node", {}).get("publish_debug_image")
    if foxglove_address(args) is None and (chosen is None or chosen.option == "--backend"):
        # Headless: nobody looks at the debug image (its drawing would take the shared
        # process's CPU from the physics), unless a --params file or -p asks for it. With
        # --foxglove it is drawn while a panel shows it.
        params.set("perception_node", "publish_debug_image", False, "--foxglove")
    if args.backend == "sim":
        params.set("sim_node", "seed", args.seed, "--seed")
        params.set("sim_node", "real_time_factor", args.real_time_factor, "--real-time-factor")


def _default_out(args) -> None:
    """The run folder: --out, else runs/demo-<time> (checked as --out would be)."""
    if args.out is None:
        try:
            args.out = writable_folder(f"runs/demo-{datetime.now():%Y%m%d-%H%M%S}")
        except argparse.ArgumentTypeError as err:
            raise CommandLineError("--out", f"(default runs/demo-<time>) {err}") from None


def parse(argv: list[str] | None) -> tuple[argparse.Namespace, list[str]]:
    """Every option and parameter file checked (cli_args.parse_command_line): a refusal exits
    2 before anything is created. Returns the arguments and the ROS arguments."""
    own, ros_args = split_ros_args(sys.argv[1:] if argv is None else list(argv))
    checks = [_default_out, graph_params_check(ros_args, lambda _: LAYERS, demo_options)]
    return parse_command_line(build_parser(), own, checks), ros_args


def report(out: Path, args, learner, recorder: FrameRecorder, finished: bool,
           clock: SessionClock) -> dict:
    """Keep this session's figures beside the log (so a resumed run's summary covers all of
    them, killed sessions included), then write summary.json and the figures of the run."""
    clock.close({
        "experiments_at_end": learner.experiments,
        "frames": [p.name for p in recorder.saved],
        "judge_checked": len(recorder.agreement), "judge_agreed": int(sum(recorder.agreement)),
        "dropped_by_reason": dict(learner.loop.dropped_total), "resets": learner.loop.resets,
        "completed": bool(finished)})
    sessions = read_sessions(out)
    checked = sum(s.get("judge_checked", 0) for s in sessions)
    agreed = sum(s.get("judge_agreed", 0) for s in sessions)
    return write_report(
        out, n_actions=learner.n_actions, max_height=learner.max_height,
        alpha=learner.rule.alpha, theta=learner.rule.theta,
        extra={"backend": args.backend, "strategy": learner.strategy_name, "seed": args.seed,
               "sessions": len(sessions),
               "wall_s": round(sum(s.get("wall_s", 0.0) for s in sessions), 1),
               "frames": [f for s in sessions for f in s.get("frames", [])],
               "judge_agrees_with_sim": round(agreed / checked, 3) if checked else None,
               "resets": sum(s.get("resets", 0) for s in sessions),
               "all_known_at": learner.loop.all_known_at,
               "completed": bool(finished)},
    )


def main(argv: list[str] | None = None) -> int:
    args, ros_args = parse(argv)
    out: Path = args.out
    new_folder = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    params = args.param_set.values()

    terminal = RunTerminal(out, verbose=args.verbose)
    try:
        return _run(args, ros_args, params, out, new_folder, terminal)
    finally:
        terminal.close()


def _run(args, ros_args: list[str], params: dict, out: Path, new_folder: bool,
         terminal: RunTerminal) -> int:
    # katana-demo handles SIGINT/SIGTERM itself (spin_nodes): the nodes stop before the context
    rclpy.init(args=["katana-demo", *ros_args], signal_handler_options=SignalHandlerOptions.NO)
    try:
        nodes = build_nodes(args.backend, params, record=args.record,
                            foxglove=foxglove_address(args))
    except Exception as exc:  # what only a node finds (a run folder it cannot resume)
        rclpy.try_shutdown()
        terminal.close()  # the refusal on standard error, not in nodes.log
        if terminal.log_path is not None and new_folder:
            terminal.log_path.unlink(missing_ok=True)
        print(f"katana-demo: {' '.join(str(exc).split())}", file=sys.stderr)
        if new_folder and not any(out.iterdir()):
            out.rmdir()
        return EXIT_INVALID_CONFIGURATION
    killed = close_killed_session(out)
    if killed is not None:
        print(f"katana-demo: the previous session was killed; its {killed['wall_s']:.0f} s are "
              f"kept in {out / 'sessions.jsonl'}", flush=True)
    recorder_node = Node("demo_frame_recorder")
    recorder = FrameRecorder(recorder_node, out / "frames", ground_truth=args.backend == "sim")
    contact = (ContactSheetRecorder(recorder_node, args.contact_first)
               if args.contact_sheet is not None else None)
    learner = next(n for n in nodes if n.get_name() == "curiosity_node")
    ended = learner.finished
    if contact is not None:  # and its last experience reached the contact sheet
        ended = threading.Event()

        def end_when_drawn() -> None:
            learner.finished.wait()
            contact.wait_for(learner.experiments - 1, CONTACT_WAIT_S)
            ended.set()

        threading.Thread(target=end_when_drawn, name="contact sheet end", daemon=True).start()
    clock = SessionClock(out, learner.experiments)
    recorder_node.create_timer(1.0, lambda: clock.beat(learner.experiments))
    shown = learner.experiments  # one line per logged experiment, from the log (complete)

    def show_new(_msg=None) -> None:
        nonlocal shown
        records = learner.log.records
        for record in records[shown:len(records)]:
            terminal.experiment(experiment_line(record.index, record.mode, record.state,
                                                record.action, record.label,
                                                record.moved_block))
        shown = len(records)

    recorder_node.create_subscription(Experience, "curiosity/experience", show_new, EVENT_QOS)
    print(f"katana-demo: backend {args.backend}, {args.experiments} experiments "
          f"(strategy {learner.strategy_name}), run folder {out}"
          + (f"; the nodes' log: {terminal.log_path}" if terminal.log_path else ""), flush=True)
    print_foxglove_url(nodes, "katana-demo")
    terminal.start(args.experiments, learner.experiments)
    start = time.monotonic()
    spin_nodes([*nodes, recorder_node], "katana-demo",
               duration_s=args.timeout or 30.0 * args.experiments + 60.0,
               executor=MultiThreadedExecutor(num_threads=EXECUTOR_THREADS),
               until=ended, limit_s=KATANA_RUN_SHUTDOWN_LIMIT_S)
    show_new()  # the last ones, whose messages the spin may have ended before
    terminal.close()
    if contact is not None and not contact.write(args.contact_sheet):
        print(f"katana-demo: no experiment from {args.contact_first} on for the contact sheet",
              file=sys.stderr)
    finished = learner.finished.is_set()
    if not finished:
        print("katana-demo: stopped before the last experiment; what was recorded is kept",
              file=sys.stderr)
    wall = time.monotonic() - start
    summary = report(out, args, learner, recorder, finished, clock)
    if summary["all_known_at"] is not None:
        print(f"katana-demo: every (height, action) pair the arm can realise was known after "
              f"{summary['all_known_at']} experiments")
    wasted = summary["wasted_experiments"]
    print(f"katana-demo: {wasted['total']} experiments wasted ({100 * wasted['fraction']:.1f} %), "
          f"longest identical plan streak {summary['longest_identical_plan_streak']}, last "
          f"query {summary['last_query']}")
    status = "done" if finished else "stopped early"
    print(f"katana-demo: {status}: {learner.experiments} experiments in {wall:.0f} s, highest "
          f"stack {summary['highest_stack']}, heights explored {summary['heights_explored']}")
    print(f"katana-demo: results in {out}/ (summary.json, model.png, experience.png, frames/)")
    return 0 if finished else 1


if __name__ == "__main__":
    sys.exit(main())
