"""katana-robot: the paper's robot experiment (sections 2.2 and 3.3) reproduced and measured.

    katana-robot truth --trials 30 --out DIR        the ground truth of the simulated world
    katana-robot paper --seeds 4 --experiments 60 --methods q1,random --jobs 2 --out DIR
    katana-robot skill --goal-height 3 --trials 10 --model RUN_DIR [--out DIR]

`truth` builds, in the fast sim, settings where the fovea realises each (height, action) pair:
it stacks blocks squarely through the real `pick_and_place` action, asks fovea/find_placement
for a location realising the pair, places a block there and reads the outcome from
sim/ground_truth (evaluation only). It writes truth.json (Wilson intervals; impossible pairs
listed as such) and truth.png.

`paper` runs one whole graph (`katana-demo`) per method and seed, each in its own process and
ROS domain, J at a time, then replays every run's experience log against the measured truth:
DIR/summary.json, DIR/runs/<method>-s<seed>/ (the run) and <method>-s<seed>.csv (per
experiment: choice, outcome, KL per height), kl.png (cf. Figures 5/9), experience.png (Figure
4), model.png (Figure 13), truth.png and contact_sheet.png (12 consecutive experiments of the
first run in the paper's four columns, cf. Figures 10-12).

`skill` starts the arm and perception with skill_node and sends build_stack goals from the same
scattered settings, with the model a run learned and with an untrained one: skill.json.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np
from katana_bringup.run import default_params_files, load_params
from katana_common.cli_args import (
    non_negative_int,
    positive_int,
    positive_seconds,
    writable_folder,
)

#: the curiosity node's default query rule on the robot (node_params), if graph.yaml sets none
DEFAULT_ALPHA, DEFAULT_THETA = 1.0, 0.1
#: where the truth measurement builds its stack: within the place reach of height 3 (0.067-0.198
#: m from the pan axis) with room for off-centre placements
STACK_XY = (0.16, 0.0)
CONTACT_ROWS = 12
#: pick_and_place phases whose camera images show the pick (block in the gripper) and
#: the place (block released)
PHASE_COLUMN = {"lift": "pick", "carry": "pick", "lower": "pick", "release": "place",
                "retreat": "place", "park": "place"}
#: settings in which the fovea found no location for a pair before it counts as never realised
UNREALISED_GIVE_UP = 3


def graph_params(seed: int, ground_truth_rate: float = 10.0) -> dict:
    """The package's graph and sim parameters, headless and on the fast sim."""
    params = load_params(default_params_files("sim"))
    params.setdefault("perception_node", {})["publish_debug_image"] = False
    params.setdefault("sim_node", {}).update(seed=seed, real_time_factor=0.0,
                                             ground_truth_rate=ground_truth_rate)
    return params


class GraphClient:
    """Bounded calls into a running graph: reset, ground truth, memory, fovea, pick-and-place."""

    def __init__(self, node, stop: threading.Event | None = None) -> None:
        from katana_common.action_client import ActionClient
        from katana_common.qos import STATE_QOS
        from katana_interfaces.action import PickAndPlace
        from katana_interfaces.msg import BlockArray
        from katana_interfaces.srv import FindPlacement, ResetWorld

        self.node = node
        self.stop = stop or threading.Event()
        self._cv = threading.Condition()
        self.truth, self.truth_count = None, 0
        self.memory, self.memory_count = None, 0
        node.create_subscription(BlockArray, "sim/ground_truth", self._on_truth, STATE_QOS)
        node.create_subscription(BlockArray, "memory/blocks", self._on_memory, STATE_QOS)
        self.reset_client = node.create_client(ResetWorld, "sim_node/reset_world")
        self.find_client = node.create_client(FindPlacement, "fovea/find_placement")
        self.pick_place = ActionClient(node, PickAndPlace, "pick_and_place")

    def _on_truth(self, msg) -> None:
        with self._cv:
            self.truth, self.truth_count = msg, self.truth_count + 1
            self._cv.notify_all()

    def _on_memory(self, msg) -> None:
        with self._cv:
            self.memory, self.memory_count = msg, self.memory_count + 1
            self._cv.notify_all()

    def wait(self, condition: Callable[[], bool], timeout_s: float, what: str) -> None:
        deadline = time.monotonic() + timeout_s
        with self._cv:
            while not condition():
                left = deadline - time.monotonic()
                if self.stop.is_set():
                    raise KeyboardInterrupt
                if left <= 0:
                    raise TimeoutError(f"no {what} within {timeout_s:.0f} s")
                self._cv.wait(min(left, 0.05))

    def wait_ready(self, timeout_s: float = 60.0) -> None:
        deadline = time.monotonic() + timeout_s
        for client in (self.reset_client, self.find_client):
            if not client.wait_for_service(timeout_sec=max(0.1, deadline - time.monotonic())):
                raise TimeoutError(f"service {client.srv_name} is not available")
        if not self.pick_place.wait_for_server(timeout_sec=max(0.1, deadline - time.monotonic())):
            raise TimeoutError("action pick_and_place is not available")
        self.wait(lambda: self.truth is not None and self.memory is not None,
                  max(0.1, deadline - time.monotonic()), "ground truth and memory")

    def call(self, client, request, timeout_s: float = 20.0):
        from katana_common.futures import wait_for_future

        return wait_for_future(client.call_async(request), timeout_s, client.srv_name,
                               stop=self.stop)

    def reset(self, seed: int) -> None:
        from katana_interfaces.srv import ResetWorld

        response = self.call(self.reset_client, ResetWorld.Request(seed=int(seed)))
        if not response.success:
            raise RuntimeError(f"reset_world: {response.message}")
        self.settled()

    def settled(self, min_sim_s: float = 0.6, timeout_s: float = 30.0) -> list:
        """Ground truth once the blocks have rested (two messages alike) for `min_sim_s` of sim
        time, and a memory/blocks from an image taken after that (two fresh messages)."""
        from katana_common.conversions import to_seconds

        with self._cv:
            start = self.truth_count
        deadline = time.monotonic() + timeout_s
        first = previous = None
        while True:
            self.wait(lambda n=start: self.truth_count > n, max(0.1, deadline - time.monotonic()),
                      "sim/ground_truth")
            with self._cv:
                msg, start = self.truth, self.truth_count
            blocks = true_blocks(msg)
            stamp = to_seconds(msg.header.stamp)
            if previous is not None and _at_rest(previous, blocks):
                first = stamp if first is None else first
                if stamp - first >= min_sim_s:
                    break
            else:
                first = None
            previous = blocks
        with self._cv:
            n = self.memory_count
        self.wait(lambda: self.memory_count >= n + 2, max(1.0, deadline - time.monotonic()),
                  "fresh memory/blocks")
        return blocks

    def pick_and_place(self, block, place_pose, timeout_s: float = 120.0):
        """Pick `block` (a ground-truth Block) and place it at `place_pose`; the result."""
        from katana_common.futures import wait_for_future
        from katana_interfaces.action import PickAndPlace

        goal = PickAndPlace.Goal(block_id=block.id, pick=block.pose, block_size=block.size,
                                 place=place_pose)
        handle = wait_for_future(self.pick_place.send_goal_async(goal), 30.0,
                                 "pick_and_place goal", stop=self.stop)
        if not handle.accepted:
            raise RuntimeError("pick_and_place rejected the goal")
        return wait_for_future(handle.get_result_async(), timeout_s, "pick_and_place result",
                               stop=self.stop).result

    def find(self, state: int, action: int):
        from katana_interfaces.srv import FindPlacement

        return self.call(self.find_client, FindPlacement.Request(state=state, action=action))


def true_blocks(msg) -> list:
    from katana_description.models import lies_flat

    from katana_paper.robot_paper import TrueBlock

    return [TrueBlock(b.id, b.pose.position.x, b.pose.position.y, b.pose.position.z,
                      int(b.level), lies_flat(b.pose.orientation.x, b.pose.orientation.y,
                                              b.pose.orientation.z, b.pose.orientation.w))
            for b in msg.blocks]


def _at_rest(a: Sequence, b: Sequence, tol_m: float = 1e-3) -> bool:
    return len(a) == len(b) and all(
        x.id == y.id and abs(x.x - y.x) < tol_m and abs(x.y - y.y) < tol_m
        and abs(x.z - y.z) < tol_m for x, y in zip(a, b, strict=True))


# -- truth ---------------------------------------------------------------------------------


@dataclass
class TruthProgress:
    placements: int = 0
    resets: int = 0
    skipped: Counter = field(default_factory=Counter)  # why trials could not be made


class TruthMeasurer:
    """Builds the settings of truth_schedule through pick_and_place and measures outcomes."""

    def __init__(self, client: GraphClient, seed: int, max_height: int, block_height_m: float,
                 log=print) -> None:
        from katana_curiosity.core.block_choice import PickReach
        from katana_manipulation.core.reach import pick_reach

        self.client, self.seed, self.max_height = client, seed, max_height
        self.block_h = block_height_m
        self.reach = PickReach(tuple((b.min_m, b.max_m) for b in (
            pick_reach(level, block_height_m) for level in range(1, max_height + 2))))
        self.stack: list[str] | None = None  # the stack built, bottom first; None: rebuild
        self.progress = TruthProgress()
        self.log = log
        self._next_seed = seed

    def _msg_block(self, bid: str):
        return next(b for b in self.client.truth.blocks if b.id == bid)

    def _free_blocks(self, exclude: Sequence[str]) -> list:
        """Loose blocks to place: flat on the table (one that fell onto its side is left
        lying, as the learning loop leaves it) and within reach."""
        from katana_description.models import lies_flat

        with self.client._cv:
            msg = self.client.truth
        return [b for b in msg.blocks if b.id not in exclude and b.on_top and b.level == 1
                and lies_flat(b.pose.orientation.x, b.pose.orientation.y,
                              b.pose.orientation.z, b.pose.orientation.w)
                and self.reach.can_pick(b.pose.position.x, b.pose.position.y, 1)]

    def _stack_intact(self, height: int) -> bool:
        if self.stack is None or len(self.stack) != height:
            return False
        with self.client._cv:
            msg = self.client.truth
        by_id = {b.id: b for b in msg.blocks}
        for level, bid in enumerate(self.stack, start=1):
            b = by_id.get(bid)
            if b is None or b.level != level:
                return False
            if level == height and not b.on_top:
                return False
        return bool(self._free_blocks(self.stack))

    def _build(self, height: int, at_xy: tuple[float, float] = STACK_XY) -> None:
        """Reset and stack `height` blocks squarely at `at_xy` (the first moved there)."""
        from geometry_msgs.msg import Pose

        for _attempt in range(10):
            self.client.reset(self._next_seed)
            self._next_seed += 1
            self.progress.resets += 1
            stack: list[str] = []
            ok = True
            for level in range(1, height + 1):
                free = self._free_blocks(stack)
                if not free:
                    ok = False
                    break
                # the block nearest the stack's spot, so the rest stay out of the way
                block = min(free, key=lambda b: math.hypot(b.pose.position.x - at_xy[0],
                                                           b.pose.position.y - at_xy[1]))
                pose = Pose()
                pose.position.x, pose.position.y = at_xy
                pose.position.z = (level - 0.5) * self.block_h
                pose.orientation.w = 1.0
                result = self.client.pick_and_place(block, pose)
                self.progress.placements += 1
                self.client.settled()
                if not result.success or self._msg_block(block.id).level != level:
                    ok = False
                    break
                stack.append(block.id)
            if ok:
                self.stack = stack
                if self._stack_intact(height):
                    return
            self.progress.skipped["stack_not_built"] += 1
        raise RuntimeError(f"could not build a stack of {height} in 10 attempts")

    def trial(self, height: int, action: int) -> int | None:
        """One placement realising (height, action): +1 stayed, -1 fell, None not made."""
        from katana_paper.robot_paper import placement_stayed

        self.last_skip = ""
        if not self._stack_intact(height):
            self._build(height)
        response = self.client.find(height, action)
        if not response.found:
            self.progress.skipped["no_fovea_location"] += 1
            self.last_skip = "no_fovea_location"
            return None
        instance = response.instance
        support = list(instance.support_ids)
        if len(support) != height:
            self.progress.skipped["fovea_support_not_of_this_height"] += 1
            self.stack = None
            return None
        # the fovea may choose another stack of this height (at height 1 any lone block):
        # that one is the setting then
        self.stack = support
        place = instance.placement.position
        free = self._free_blocks(self.stack)
        block = max(free, key=lambda b: math.hypot(b.pose.position.x - place.x,
                                                   b.pose.position.y - place.y))
        before = true_blocks(self.client.truth)
        result = self.client.pick_and_place(block, instance.placement)
        self.progress.placements += 1
        after = self.client.settled()
        if not result.success:
            self.progress.skipped[f"pick_and_place_code_{result.error_code}"] += 1
            self.stack = None
            return None
        stayed = placement_stayed(before, after, block.id, self.stack)
        if stayed and height > 0:
            self.stack = None  # the stack is higher now: build anew
        return 1 if stayed else -1


def cmd_truth(args) -> int:
    from katana_bringup.run import build_nodes
    from katana_bringup.testing import InProcessGraph

    from katana_paper.robot_paper import truth_figure, truth_schedule
    from katana_paper.robot_truth import TruthTable

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    params = graph_params(args.seed)
    block_h = float(params["/**"].get("block_size", [0.04, 0.04, 0.03])[2])
    table = TruthTable(args.max_height + 1, args.actions)
    for a in range(2, args.actions + 1):
        table.mark_impossible(0, a)
    schedule = truth_schedule(args.trials, args.max_height, args.actions)
    start = time.monotonic()
    with InProcessGraph() as g:
        g.add(*build_nodes("sim", params, g.context, layers=("arm", "perception")))
        client = GraphClient(g.node("truth_measurer"))
        client.wait_ready()
        measurer = TruthMeasurer(client, args.seed, args.max_height, block_h)
        tries, never_realised = Counter(), set()
        try:
            for height, action in schedule:
                label, fails = None, 0
                while (height, action) not in never_realised and label is None \
                        and fails < UNREALISED_GIVE_UP and tries[height, action] < args.trials * 3:
                    tries[height, action] += 1
                    try:
                        label = measurer.trial(height, action)
                    except TimeoutError as exc:  # a slow graph: set this one up again
                        print(f"katana-robot truth: {exc}; building anew", file=sys.stderr)
                        measurer.progress.skipped["timeout"] += 1
                        measurer.stack, label = None, None
                        continue
                    if label is None and measurer.last_skip == "no_fovea_location":
                        fails += 1
                        measurer.stack = None  # another scatter, another stack
                if label is None and fails >= UNREALISED_GIVE_UP \
                        and table.trials[height, action - 1] == 0:
                    never_realised.add((height, action))  # not tried again in later rounds
                if label is not None:
                    table.record(height, action, label)
                done = int(table.trials.sum())
                outcome = f"{label:+d}" if label is not None else (
                    "not made: " + ", ".join(f"{k} x{v}" for k, v in
                                             measurer.progress.skipped.items()))
                print(f"katana-robot truth: height {height} action {action}: "
                      f"{outcome} ({done}/{len(schedule)} "
                      f"trials, {measurer.progress.placements} placements, "
                      f"{time.monotonic() - start:.0f} s)", flush=True)
                if done % 10 == 0:
                    table.save(out / "truth.json")
        except KeyboardInterrupt:
            print("katana-robot truth: interrupted; the trials so far are kept", file=sys.stderr)
    # pairs the fovea never realised in the settings it was shown stay unmeasured (null), listed
    # apart: they may be impossible for this fovea or this memory, not for the physics
    never = sorted([h, a] for h, a in never_realised if table.trials[h, a - 1] == 0)
    table.save(out / "truth.json")
    data = json.loads((out / "truth.json").read_text())
    data["never_realised_by_the_fovea"] = never
    data["measurement"] = {"trials_per_pair": args.trials, "seed": args.seed,
                           "placements": measurer.progress.placements,
                           "resets": measurer.progress.resets,
                           "skipped": dict(measurer.progress.skipped),
                           "wall_s": round(time.monotonic() - start, 1)}
    (out / "truth.json").write_text(json.dumps(data, indent=1) + "\n")
    truth_figure(table, out / "truth.png")
    print(f"katana-robot truth: {int(table.trials.sum())} trials in "
          f"{time.monotonic() - start:.0f} s -> {out}/truth.json, truth.png")
    print(truth_text(table))
    return 0


def truth_text(table) -> str:
    p = table.p_stable()
    lines = ["height  " + "  ".join(f"a{a + 1:<5}" for a in range(table.n_actions))]
    for h in range(table.n_states):
        cells = []
        for a in range(table.n_actions):
            if not table.possible[h, a]:
                cells.append("  -   ")
            elif np.isnan(p[h, a]):
                cells.append("  ?   ")
            else:
                cells.append(f"{p[h, a]:.2f}  ")
        lines.append(f"{h:<8}" + " ".join(cells))
    return "\n".join(lines)


# -- paper ---------------------------------------------------------------------------------


def _run_name(method: str, seed: int) -> str:
    return f"{method}-s{seed}"


class ContactRecorder:
    """Frames of 12 consecutive experiments of a run in another process, in the paper's four
    columns: the scene before (fovea and placement drawn at the end), the first image after
    the grasp, the first after the release, and the image the judge saw, with the label."""

    def __init__(self, domain_id: int, first: int, rows: int = CONTACT_ROWS) -> None:
        import rclpy
        from katana_common.qos import SENSOR_QOS
        from katana_interfaces.action import PickAndPlace
        from katana_interfaces.msg import Experience
        from katana_perception.conversions import image_to_rgb
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from sensor_msgs.msg import Image

        self.first, self.n = first, rows
        # the run is another process on this machine: discovery must reach it (read once, at
        # init; the process's own setting is put back for anything started later)
        saved = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE")
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        self.context = Context()
        try:
            rclpy.init(context=self.context, domain_id=domain_id)
        finally:
            if saved is None:
                del os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"]
            else:
                os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = saved
        self.node = Node("contact_recorder", context=self.context)
        self._to_rgb = image_to_rgb
        self._lock = threading.Lock()
        self.latest = None
        self.current: dict = {}
        self.wanted: str | None = None
        self.rows: list[dict] = []
        self._pending = None  # the last row, until the next motion shows its outcome
        self.node.create_subscription(Image, "camera/image_raw", self._on_image, SENSOR_QOS)
        self.node.create_subscription(Experience, "curiosity/experience", self._on_experience,
                                      10)
        self.node.create_subscription(PickAndPlace.Impl.FeedbackMessage,
                                      "pick_and_place/_action/feedback", self._on_feedback, 10)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._stop = threading.Event()
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set() and self.context.ok():
            self.executor.spin_once(timeout_sec=0.05)

    def _on_image(self, msg) -> None:
        try:
            rgb = self._to_rgb(msg)
        except ValueError:
            return
        with self._lock:
            self.latest = rgb
            slot = PHASE_COLUMN.get(self.wanted or "")
            if slot and slot not in self.current:
                self.current[slot] = rgb

    def _on_feedback(self, msg) -> None:
        with self._lock:
            if "before" not in self.current and self.latest is not None:
                self.current["before"] = self.latest
                if self._pending is not None:  # the scene before this motion is the scene
                    row, draw = self._pending  # the last experiment left: its observation
                    row["images"][3] = draw(self.latest)
                    self._pending = None
            self.wanted = msg.feedback.phase

    def _on_experience(self, msg) -> None:
        with self._lock:
            frames, self.current, self.wanted = self.current, {}, None
            latest = self.latest
        if not self.first <= msg.index < self.first + self.n or len(self.rows) >= self.n:
            return
        from katana_bringup.demo import draw_placement

        inst = msg.instance
        import cv2

        def drawn(img, **kw):
            if img is None:
                return None
            return cv2.cvtColor(draw_placement(img, inst.pixel_u, inst.pixel_v, inst.bits, "",
                                               **kw), cv2.COLOR_BGR2RGB)

        row = {
            "caption": f"#{msg.index} {msg.mode}\nh={inst.state} a={inst.action}\n"
                       f"{'stayed' if msg.label > 0 else 'fell'} ({msg.label:+d})",
            "label": int(msg.label),
            "images": [drawn(frames.get("before")), frames.get("pick"), frames.get("place"),
                       drawn(latest, stable=msg.label > 0)],
        }
        with self._lock:
            self.rows.append(row)
            self._pending = (row, partial(drawn, stable=msg.label > 0))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()
        import rclpy

        rclpy.try_shutdown(context=self.context)


def _launch(method: str, seed: int, experiments: int, run_dir: Path, domain: int,
            extra: Sequence[str]) -> subprocess.Popen:
    run_dir.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    cmd = [shutil.which("katana-demo") or "katana-demo", "--experiments", str(experiments),
           "--strategy", method, "--seed", str(seed), "--out", str(run_dir), *extra]
    log = open(run_dir / "stdout.log", "w", encoding="utf-8")  # noqa: SIM115 (closed by caller)
    proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT)
    proc.log = log  # type: ignore[attr-defined]
    return proc


def _end(proc: subprocess.Popen, grace_s: float = 10.0) -> int:
    """SIGINT (katana-demo keeps what it recorded), then SIGKILL after `grace_s`."""
    import signal

    proc.send_signal(signal.SIGINT)
    try:
        code = proc.wait(timeout=grace_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        code = proc.wait()
    proc.log.close()
    return code


def _complete(run: Path, experiments: int) -> bool:
    from katana_curiosity.core.run_record import LOG_NAME, ExperienceLog

    log = run / LOG_NAME
    return log.exists() and len(ExperienceLog(log)) >= experiments


def run_all(jobs: Sequence[tuple[str, int]], experiments: int, out: Path, parallel: int,
            domain_base: int, timeout_s: float, contact_first: int | None,
            reuse: bool = False) -> dict[str, int]:
    """Each (method, seed) a katana-demo in its own process and ROS domain, `parallel` at a
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
                method, seed = pending.pop(0)
                name = _run_name(method, seed)
                if reuse and _complete(out / "runs" / name, experiments):
                    codes[name] = 0
                    print(f"katana-robot paper: {name} is complete already; reused", flush=True)
                    continue
                if contact_first is not None and recorder is None and not running:
                    # the first run launched (reused ones are complete already)
                    recorder = ContactRecorder(domain_base + slot, contact_first)
                proc = _launch(method, seed, experiments, out / "runs" / name,
                               domain_base + slot, [])
                running[slot] = (name, proc, time.monotonic())
                print(f"katana-robot paper: started {name} (domain {domain_base + slot})",
                      flush=True)
            for slot, (name, proc, t0) in list(running.items()):
                code = proc.poll()
                if code is None and time.monotonic() - t0 > timeout_s:
                    code = _end(proc)
                if code is not None:
                    if not proc.log.closed:
                        proc.log.close()
                    codes[name] = code
                    del running[slot]
                    print(f"katana-robot paper: {name} ended ({code}) after "
                          f"{time.monotonic() - t0:.0f} s", flush=True)
            time.sleep(0.2)
    finally:
        for name, proc, _ in running.values():
            _end(proc)
            codes.setdefault(name, -15)
        if recorder is not None:
            recorder.close()
            if recorder.rows:
                from katana_paper.robot_paper import contact_sheet

                contact_sheet(recorder.rows, out / "contact_sheet.png")
    return codes


def query_rule() -> tuple[float, float]:
    params = load_params(default_params_files("sim")).get("curiosity_node", {})
    return float(params.get("alpha", DEFAULT_ALPHA)), float(params.get("theta", DEFAULT_THETA))


def analyse(out: Path, jobs: Sequence[tuple[str, int]], truth_path: Path, experiments: int,
            seeds: Sequence[int]) -> dict:
    """summary.json, the per-run CSVs and the figures from the runs in out/runs."""
    from katana_curiosity.core.run_record import LOG_NAME, ExperienceLog

    from katana_paper import robot_paper as rp
    from katana_paper.robot_truth import TruthTable

    truth = TruthTable.load(truth_path)
    alpha, theta = query_rule()
    analyses = []
    for method, seed in jobs:
        run = out / "runs" / _run_name(method, seed)
        records = ExperienceLog(run / LOG_NAME).records if (run / LOG_NAME).exists() else []
        a = rp.analyse_run(records, truth, method, seed, alpha=alpha, theta=theta)
        rp.write_run_csv(a, out / f"{_run_name(method, seed)}.csv")
        analyses.append(a)
    summary = rp.summarise(analyses, experiments, seeds, str(truth_path))
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    usable = [a for a in analyses if len(a.states)]
    if usable:
        rp.kl_figure(usable, out / "kl.png")
        rp.experience_figure(usable, out / "experience.png", usable[0].method)
        rp.model_figure(usable[0], truth, out / "model.png")
    rp.truth_figure(truth, out / "truth.png")
    return summary


def cmd_paper(args) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    truth = Path(args.truth)
    if not truth.exists():
        print(f"katana-robot paper: no measured truth at {truth}; run `katana-robot truth` "
              "first or pass --truth", file=sys.stderr)
        return 2
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    seeds = list(range(args.seed0, args.seed0 + args.seeds))
    jobs = [(m, s) for s in seeds for m in methods]
    start = time.monotonic()
    import signal

    def _interrupt(_signum, _frame):  # SIGTERM: end the runs as Ctrl-C does
        raise KeyboardInterrupt

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
    for method, m in summary["methods"].items():
        print(f"katana-robot paper: {method}: final KL {m['final_kl']} (overall "
              f"{m['final_kl_overall']}), highest stack {m['highest_stack']}, "
              f"{m['s_per_experiment']} s/experiment, wasted {m['wasted_share']}")
    print(f"katana-robot paper: {len(jobs)} runs in {wall:.0f} s -> {out}/summary.json")
    return 0 if all(c == 0 for c in codes.values()) else 1


# -- skill ---------------------------------------------------------------------------------


def skill_trials(model: str, goal_height: int, trials: int, seed: int, max_placements: int,
                 log=print) -> dict:
    """`trials` build_stack goals, each from the scatter reset_world(seed + k) makes."""
    from katana_bringup.run import build_nodes, overrides_for
    from katana_bringup.testing import InProcessGraph
    from katana_common.action_client import ActionClient
    from katana_curiosity.skill_node import SkillNode
    from katana_interfaces.action import BuildStack
    from rclpy.parameter import Parameter

    params = graph_params(seed)
    params["skill_node"] = {"model": model}
    outcomes = []
    with InProcessGraph() as g:
        g.add(*build_nodes("sim", params, g.context, layers=("arm", "perception")))
        g.add(SkillNode(context=g.context, parameter_overrides=[
            p for p in overrides_for("skill_node", params)
            if p.name in ("model", "world_frame", "block_size")]
            + [Parameter("max_placements", value=max_placements)]))
        node = g.node("skill_client")
        client = GraphClient(node)
        client.wait_ready()
        action = ActionClient(node, BuildStack, "build_stack")
        if not action.wait_for_server(timeout_sec=30.0):
            raise TimeoutError("build_stack is not available")
        for k in range(trials):
            client.reset(seed + k)
            feedback: list = []
            handle = g.result(action.send_goal_async(
                BuildStack.Goal(target_height=goal_height, max_placements=max_placements),
                feedback_callback=lambda f, fb=feedback: fb.append(f.feedback)), 30.0)
            result = g.result(handle.get_result_async(), 60.0 * max_placements + 60.0).result
            truth_height = max((b.level for b in client.settled(0.3)), default=0)
            outcomes.append({
                "seed": seed + k, "success": bool(result.success), "reason": result.reason,
                "height_reached": int(result.height_reached), "truth_height": int(truth_height),
                "placements": int(result.placements), "falls": int(result.falls),
                "choices": [[int(f.state), int(f.action), round(float(f.predicted_success), 3),
                             int(f.observed_label)] for f in feedback]})
            log(f"katana-robot skill ({model or 'untrained'}): trial {k}: {result.reason}, "
                f"height {result.height_reached} (sim {truth_height}), {result.placements} "
                f"placements, {result.falls} falls")
    wins = [o for o in outcomes if o["success"] and o["truth_height"] >= goal_height]
    return {"model": model or "untrained", "trials": trials, "goal_height": goal_height,
            "success_rate": len(wins) / trials if trials else None,
            "placements_per_success": (sum(o["placements"] for o in wins) / len(wins))
            if wins else None,
            "falls": sum(o["falls"] for o in outcomes), "outcomes": outcomes}


def cmd_skill(args) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    models = [str(args.model)] + ([] if args.no_untrained else [""])
    report = {"goal_height": args.goal_height, "trials": args.trials, "seed": args.seed,
              "max_placements": args.max_placements, "models": []}
    for model in models:
        report["models"].append(skill_trials(model, args.goal_height, args.trials, args.seed,
                                             args.max_placements))
        (out / "skill.json").write_text(json.dumps(report, indent=1) + "\n")
    print(f"{'model':<40} {'success':>8} {'placements/success':>19} {'falls':>6}")
    for m in report["models"]:
        pps = m["placements_per_success"]
        print(f"{m['model']:<40} {m['success_rate']:>8.2f} "
              f"{'-' if pps is None else f'{pps:.1f}':>19} {m['falls']:>6}")
    print(f"katana-robot skill: -> {out}/skill.json")
    return 0


# -- command line --------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="katana-robot", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)

    t = sub.add_parser("truth", help="measure P(stays) per (height, action) in the sim")
    t.add_argument("--trials", type=positive_int, default=30, help="placements per pair")
    t.add_argument("--out", type=writable_folder, default="runs/robot-truth")
    t.add_argument("--seed", type=non_negative_int, default=0, help="first reset seed")
    t.add_argument("--max-height", type=int, default=3, choices=range(1, 4))
    t.add_argument("--actions", type=int, default=6, choices=(6,))

    p = sub.add_parser("paper", help="multi-seed robot runs against the measured truth")
    p.add_argument("--seeds", type=positive_int, default=4)
    p.add_argument("--seed0", type=non_negative_int, default=0, help="first seed")
    p.add_argument("--experiments", type=positive_int, default=60)
    p.add_argument("--methods", default="q1,random")
    p.add_argument("--jobs", type=positive_int, default=2, help="runs at a time")
    p.add_argument("--out", type=writable_folder, default="runs/robot-paper")
    p.add_argument("--truth", default="runs/robot-truth/truth.json")
    p.add_argument("--domain-base", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", 0)),
                   help="ROS domain of the first parallel slot (default: $ROS_DOMAIN_ID)")
    p.add_argument("--run-timeout", type=positive_seconds, default=None, metavar="S")
    p.add_argument("--contact-first", type=int, default=0,
                   help="first experiment of the contact sheet (first run)")
    p.add_argument("--no-contact-sheet", action="store_true")
    p.add_argument("--reuse", action="store_true",
                   help="keep runs whose log already holds --experiments (re-analyse only)")

    s = sub.add_parser("skill", help="build_stack with a learned and an untrained model")
    s.add_argument("--goal-height", type=int, default=3, choices=range(1, 5))
    s.add_argument("--trials", type=positive_int, default=10)
    s.add_argument("--model", required=True, help="a run folder (learner.npz) or a file")
    s.add_argument("--seed", type=non_negative_int, default=100,
                   help="reset seed of the first trial")
    s.add_argument("--max-placements", type=positive_int, default=12)
    s.add_argument("--out", type=writable_folder, default="runs/robot-skill")
    s.add_argument("--no-untrained", action="store_true")

    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.command == "paper":
        from katana_curiosity.core.explorer import STRATEGIES

        bad = [m for m in args.methods.split(",") if m.strip() not in STRATEGIES]
        if bad:
            parser.error(f"--methods: unknown {bad}; choose from {sorted(STRATEGIES)}")
        if not 0 <= args.domain_base <= 232 - args.jobs:
            parser.error("--domain-base must leave room for --jobs domains within 0..232")
    if args.command == "skill":
        model = Path(args.model)
        if not (model / "learner.npz").exists() and not model.is_file():
            parser.error(f"--model: no learner.npz in {model}")
    commands = {"truth": cmd_truth, "paper": cmd_paper, "skill": cmd_skill}
    return commands[args.command](args)


if __name__ == "__main__":
    sys.exit(main())
