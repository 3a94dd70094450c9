"""`katana-robot truth`: the ground truth of the simulated world, measured.

In the fast sim, settings are built where the fovea realises each (height, action) pair: blocks
are stacked squarely through the real `pick_and_place` action, fovea/find_placement is asked
for a location realising the pair, a block is placed there and the outcome read from
sim/ground_truth (evaluation only). Writes truth.json (Wilson intervals; impossible pairs listed
as such) and truth.png.
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from geometry_msgs.msg import Pose
from katana_bringup.in_process import InProcessGraph
from katana_bringup.run import build_nodes
from katana_curiosity.core.block_choice import PickReach
from katana_manipulation.core.reach import pick_reach

from .graph_client import GraphClient, graph_params, lies_flat_msg, true_blocks
from .robot_paper import truth_figure
from .robot_truth import TruthTable, placement_stayed, truth_schedule

#: where the truth measurement builds its stack: within the place reach of height 3 (0.067-0.198
#: m from the pan axis) with room for off-centre placements
STACK_XY = (0.16, 0.0)
#: settings in which the fovea found no location for a pair before it counts as never realised
UNREALISED_GIVE_UP = 3


@dataclass
class TruthProgress:
    placements: int = 0
    resets: int = 0
    skipped: Counter = field(default_factory=Counter)  # why trials could not be made


class TruthMeasurer:
    """Builds the settings of truth_schedule through pick_and_place and measures outcomes."""

    def __init__(self, client: GraphClient, seed: int, max_height: int, block_height_m: float,
                 log=print) -> None:
        self.client, self.seed, self.max_height = client, seed, max_height
        self.block_h = block_height_m
        self.reach = PickReach(tuple((b.min_m, b.max_m) for b in (
            pick_reach(level, block_height_m) for level in range(1, max_height + 2))))
        self.stack: list[str] | None = None  # the stack built, bottom first; None: rebuild
        self.progress = TruthProgress()
        self.log = log
        self.last_skip = ""
        self._next_seed = seed

    def _msg_block(self, bid: str):
        return next(b for b in self.client.latest_truth().blocks if b.id == bid)

    def _free_blocks(self, exclude: Sequence[str]) -> list:
        """Loose blocks to place: flat on the table (one that fell onto its side is left
        lying, as the learning loop leaves it) and within reach."""
        return [b for b in self.client.latest_truth().blocks
                if b.id not in exclude and b.on_top and b.level == 1 and lies_flat_msg(b)
                and self.reach.can_pick(b.pose.position.x, b.pose.position.y, 1)]

    def _stack_intact(self, height: int) -> bool:
        if self.stack is None or len(self.stack) != height:
            return False
        by_id = {b.id: b for b in self.client.latest_truth().blocks}
        for level, bid in enumerate(self.stack, start=1):
            b = by_id.get(bid)
            if b is None or b.level != level:
                return False
            if level == height and not b.on_top:
                return False
        return bool(self._free_blocks(self.stack))

    def _stack_once(self, height: int, at_xy: tuple[float, float]) -> list[str] | None:
        """Reset, then stack `height` blocks squarely at `at_xy`: the stack, or None."""
        self.client.reset(self._next_seed)
        self._next_seed += 1
        self.progress.resets += 1
        stack: list[str] = []
        for level in range(1, height + 1):
            free = self._free_blocks(stack)
            if not free:
                return None
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
                return None
            stack.append(block.id)
        return stack

    def _build(self, height: int, at_xy: tuple[float, float] = STACK_XY) -> None:
        """Reset and stack `height` blocks squarely at `at_xy` (the first moved there)."""
        for _attempt in range(10):
            stack = self._stack_once(height, at_xy)
            if stack is not None:
                self.stack = stack
                if self._stack_intact(height):
                    return
            self.progress.skipped["stack_not_built"] += 1
        raise RuntimeError(f"could not build a stack of {height} in 10 attempts")

    def _skip(self, reason: str, rebuild: bool = True) -> None:
        self.progress.skipped[reason] += 1
        if rebuild:
            self.stack = None

    def trial(self, height: int, action: int) -> int | None:
        """One placement realising (height, action): +1 stayed, -1 fell, None not made."""
        self.last_skip = ""
        if not self._stack_intact(height):
            self._build(height)
        response = self.client.find(height, action)
        if not response.found:
            self._skip("no_fovea_location", rebuild=False)
            self.last_skip = "no_fovea_location"
            return None
        instance = response.instance
        support = list(instance.support_ids)
        if len(support) != height:
            self._skip("fovea_support_not_of_this_height")
            return None
        # the fovea may choose another stack of this height (at height 1 any lone block):
        # that one is the setting then
        self.stack = support
        place = instance.placement.position
        free = self._free_blocks(self.stack)
        if not free:  # the rest lie on their side or out of reach: another scatter
            self._skip("no_free_block")
            self.last_skip = "no_free_block"
            return None
        block = max(free, key=lambda b: math.hypot(b.pose.position.x - place.x,
                                                   b.pose.position.y - place.y))
        before = true_blocks(self.client.latest_truth())
        result = self.client.pick_and_place(block, instance.placement)
        self.progress.placements += 1
        after = self.client.settled()
        if not result.success:
            self._skip(f"pick_and_place_code_{result.error_code}")
            return None
        stayed = placement_stayed(before, after, block.id, self.stack)
        if stayed and height > 0:
            self.stack = None  # the stack is higher now: build anew
        return 1 if stayed else -1


def measure_pair(measurer: TruthMeasurer, height: int, action: int, tries: Counter,
                 max_tries: int) -> tuple[int | None, int]:
    """Trials of (height, action) until one is made: its label (None: none made) and in how
    many settings the fovea found no location for the pair."""
    label, fails = None, 0
    while label is None and fails < UNREALISED_GIVE_UP and tries[height, action] < max_tries:
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
    return label, fails


def measure(measurer: TruthMeasurer, table: TruthTable, schedule: list[tuple[int, int]],
            trials: int, out: Path, start: float) -> set[tuple[int, int]]:
    """Every pair of `schedule` into `table` (saved every ten trials); the pairs the fovea
    never realised, which are not tried again in later rounds."""
    tries: Counter = Counter()
    never_realised: set[tuple[int, int]] = set()
    for height, action in schedule:
        if (height, action) in never_realised:
            label, fails = None, 0
        else:
            label, fails = measure_pair(measurer, height, action, tries, trials * 3)
        if label is None and fails >= UNREALISED_GIVE_UP \
                and table.trials[height, action - 1] == 0:
            never_realised.add((height, action))
        if label is not None:
            table.record(height, action, label)
        done = int(table.trials.sum())
        outcome = f"{label:+d}" if label is not None else (
            "not made: " + ", ".join(f"{k} x{v}" for k, v in measurer.progress.skipped.items()))
        print(f"katana-robot truth: height {height} action {action}: {outcome} "
              f"({done}/{len(schedule)} trials, {measurer.progress.placements} placements, "
              f"{time.monotonic() - start:.0f} s)", flush=True)
        if done % 10 == 0:
            table.save(out / "truth.json")
    return never_realised


def cmd_truth(args) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    params = graph_params(args.seed)
    block_h = float(params["/**"].get("block_size", [0.04, 0.04, 0.03])[2])
    table = TruthTable(args.max_height + 1, args.actions)
    for a in range(2, args.actions + 1):
        table.mark_impossible(0, a)
    schedule = truth_schedule(args.trials, args.max_height, args.actions)
    start = time.monotonic()
    never_realised: set[tuple[int, int]] = set()
    with InProcessGraph() as g:
        g.add(*build_nodes("sim", params, g.context, layers=("arm", "perception")))
        client = GraphClient(g.node("truth_measurer"))
        client.wait_ready()
        measurer = TruthMeasurer(client, args.seed, args.max_height, block_h)
        try:
            never_realised = measure(measurer, table, schedule, args.trials, out, start)
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


def truth_text(table: TruthTable) -> str:
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
