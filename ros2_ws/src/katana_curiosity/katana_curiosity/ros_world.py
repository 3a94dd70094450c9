"""The explorer's world protocol over ROS 2: fovea services, pick-and-place, the judge.

Runs on the curiosity node's experiment thread. Every call waits on a future with a timeout
while the node's executor spins elsewhere, so nothing blocks a callback and nothing hangs.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field

import numpy as np
from katana_interfaces.action import PickAndPlace
from katana_interfaces.msg import BlockArray, FoveaInstance
from katana_interfaces.srv import FindPlacement, JudgePlacement, ObserveSetting, ResetWorld
from rclpy.action import ActionClient
from rclpy.client import Client
from rclpy.node import Node

from .core.block_choice import BlockView, choose_block_to_move
from .core.world import PlacementUnavailable, Setting


class ExperimentAborted(RuntimeError):
    """The experiment could not be completed; nothing is learned from it."""


@dataclass
class Execution:
    """What the world did for the last experiment (for the log)."""

    instance: FoveaInstance
    setting: int
    available: list[int]
    moved_block: str
    attempts: int
    stage_s: dict = field(default_factory=dict)


@dataclass
class Timeouts:
    service_s: float = 10.0
    action_s: float = 120.0
    blocks_s: float = 10.0


def wait_future(future, timeout_s: float, what: str):
    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    if not done.wait(timeout_s):
        future.cancel()
        raise TimeoutError(f"{what}: no answer within {timeout_s:.1f} s")
    return future.result()


def call_service(client: Client, request, timeout_s: float):
    if not client.wait_for_service(timeout_sec=timeout_s):
        raise TimeoutError(f"service {client.srv_name} is not available")
    return wait_future(client.call_async(request), timeout_s, f"service {client.srv_name}")


class RosWorld:
    """World (katana_curiosity.core.world) backed by the node graph of DESIGN.md."""

    def __init__(
        self,
        node: Node,
        *,
        n_actions: int,
        max_height: int,
        grasp_retries: int,
        timeouts: Timeouts,
        reach: tuple[float, float],
        reach_by_level: tuple[float, ...] = (),
        callback_group=None,
    ) -> None:
        self.node = node
        self.n_actions, self.max_height = n_actions, max_height
        self.grasp_retries, self.timeouts, self.reach = grasp_retries, timeouts, reach
        self.reach_by_level = reach_by_level
        kw = {"callback_group": callback_group}
        self.observe_client = node.create_client(ObserveSetting, "fovea/observe", **kw)
        self.find_client = node.create_client(FindPlacement, "fovea/find_placement", **kw)
        self.judge_client = node.create_client(JudgePlacement, "perception/judge_placement", **kw)
        self.pick_place = ActionClient(node, PickAndPlace, "pick_and_place", **kw)
        reset_name = node.get_parameter("reset_service").value
        self.reset_client = node.create_client(ResetWorld, reset_name, **kw)
        self._blocks: BlockArray | None = None
        self._blocks_count = 0
        self._blocks_cv = threading.Condition()
        self.instances: list[FoveaInstance] = []
        self.setting_id = 0
        self.observe_s = 0.0
        self.last: Execution | None = None
        # blocks the arm could not pick, with where they were: skipped until they move
        self.unpickable: dict[str, tuple[float, float]] = {}

    # -- world/blocks --------------------------------------------------------------------

    def on_blocks(self, msg: BlockArray) -> None:
        with self._blocks_cv:
            self._blocks = msg
            self._blocks_count += 1
            self._blocks_cv.notify_all()

    def blocks(self) -> BlockArray | None:
        with self._blocks_cv:
            return self._blocks

    def wait_for_blocks(self, newer_than: int | None = None) -> BlockArray:
        """The latest world/blocks, or the first one after message number `newer_than`."""
        deadline = time.monotonic() + self.timeouts.blocks_s
        with self._blocks_cv:
            while self._blocks is None or (
                newer_than is not None and self._blocks_count <= newer_than
            ):
                left = deadline - time.monotonic()
                if left <= 0 or not self.node.context.ok():
                    raise TimeoutError(
                        f"no fresh world/blocks within {self.timeouts.blocks_s:.1f} s"
                    )
                self._blocks_cv.wait(min(left, 0.5))
            return self._blocks

    def blocks_count(self) -> int:
        with self._blocks_cv:
            return self._blocks_count

    # -- protocol ------------------------------------------------------------------------

    def observe(self) -> Setting:
        start = time.perf_counter()
        request = ObserveSetting.Request(max_state=self.max_height)
        response = call_service(self.observe_client, request, self.timeouts.service_s)
        self.observe_s = time.perf_counter() - start
        if not response.success:
            raise PlacementUnavailable(f"fovea/observe: {response.message}")
        usable = [
            inst
            for inst in response.instances
            if inst.state <= self.max_height and 1 <= inst.action <= self.n_actions
        ]
        # Available means executable (paper 2.2: availability comes from the known blocks): a
        # placement needs a block the arm can pick that is not part of the target stack.
        blocks = self.blocks()
        if blocks is not None:
            usable = [inst for inst in usable if self._choose_block(blocks, inst, set())]
        if not usable:
            raise PlacementUnavailable("fovea/observe listed no instance with a block to move")
        self.instances = usable
        self.setting_id = int(response.setting)
        states = np.array([inst.state for inst in usable])
        actions = np.array([inst.action - 1 for inst in usable])
        return Setting.from_pairs(states, actions)

    def execute(self, state: int, action: int, index: int | None = None) -> int:
        stages: dict[str, float] = {"observe_s": self.observe_s}
        start = time.perf_counter()
        if index is not None:
            instance = self.instances[index]
        else:
            instance = self.find_placement(state, action)
        stages["find_s"] = time.perf_counter() - start

        t = time.perf_counter()
        self._judge(JudgePlacement.Request.PHASE_BEFORE, instance, "")
        stages["judge_before_s"] = time.perf_counter() - t

        t = time.perf_counter()
        moved, attempts = self._pick_and_place(instance)
        stages["pick_place_s"] = time.perf_counter() - t

        # The arm is parked now; judge on an image taken after that, as the paper's robot does.
        # One new world/blocks may come from an image captured during the last motion, the
        # second cannot.
        t = time.perf_counter()
        self.wait_for_blocks(newer_than=self.blocks_count() + 1)
        stages["settle_s"] = time.perf_counter() - t

        t = time.perf_counter()
        label = self._judge(JudgePlacement.Request.PHASE_AFTER, instance, moved)
        stages["judge_s"] = time.perf_counter() - t
        if label not in (-1, 1):
            raise ExperimentAborted(f"the judge gave no verdict (label {label})")
        available = sorted({int(i.state) for i in self.instances})
        self.last = Execution(instance, self.setting_id, available, moved, attempts, stages)
        return label

    # -- steps ---------------------------------------------------------------------------

    def find_placement(self, state: int, action: int) -> FoveaInstance:
        # plain ints: the generated C conversion aborts the process on a numpy integer
        request = FindPlacement.Request(state=int(state), action=int(action) + 1)
        response = call_service(self.find_client, request, self.timeouts.service_s)
        if not response.found:
            raise PlacementUnavailable(
                f"no fovea location realises (s={state}, a={action + 1}): {response.message}"
            )
        return response.instance

    def _judge(self, phase: int, instance: FoveaInstance, placed: str) -> int:
        request = JudgePlacement.Request(phase=phase, instance=instance, placed_block=placed)
        response = call_service(self.judge_client, request, self.timeouts.service_s)
        if not response.success:
            raise ExperimentAborted(f"perception/judge_placement: {response.message}")
        return int(response.label)

    def _pick_and_place(self, instance: FoveaInstance) -> tuple[str, int]:
        """Move the chosen block; a missed grasp is retried (the paper resets and tries again)."""
        excluded: set[str] = set()
        attempts = 0
        while True:
            attempts += 1
            blocks = self.wait_for_blocks()
            block = self._choose_block(blocks, instance, excluded)
            if block is None:
                raise PlacementUnavailable("no accessible block to move for this placement")
            goal = PickAndPlace.Goal(
                block_id=block.id,
                pick=block.pose,
                block_size=block.size,
                place=instance.placement,
            )
            result = self._send_pick_place(goal)
            if result.success:
                return block.id, attempts
            code = result.error_code
            reason = f"pick_and_place of {block.id}: {result.message} (code {code})"
            if code == PickAndPlace.Result.UNREACHABLE and self._place_unreachable(result):
                raise PlacementUnavailable(reason)
            if code == PickAndPlace.Result.UNREACHABLE:
                excluded.add(block.id)  # try another block, now and until this one moves
                self.unpickable[block.id] = (block.pose.position.x, block.pose.position.y)
            elif code != PickAndPlace.Result.GRASP_MISSED:
                raise ExperimentAborted(reason)
            if attempts > self.grasp_retries:
                raise ExperimentAborted(f"{reason}; gave up after {attempts} attempts")
            self.node.get_logger().warning(f"{reason}; retrying")

    def _still_unpickable(self, block) -> bool:
        where = self.unpickable.get(block.id)
        if where is None:
            return False
        if math.hypot(block.pose.position.x - where[0], block.pose.position.y - where[1]) < 0.005:
            return True
        del self.unpickable[block.id]  # it moved: worth trying again
        return False

    @staticmethod
    def _place_unreachable(result) -> bool:
        return "place" in result.message.lower()

    def _choose_block(self, blocks: BlockArray, instance: FoveaInstance, excluded: set[str]):
        views = {
            b.id: BlockView(b.id, b.pose.position.x, b.pose.position.y, b.on_top, b.level)
            for b in blocks.blocks
            if b.id not in excluded and not self._still_unpickable(b)
        }
        def reachable(view: BlockView) -> bool:
            return self.pick_reachable(view.x, view.y, view.level)

        choice = choose_block_to_move(
            views.values(),
            (instance.placement.position.x, instance.placement.position.y),
            list(instance.support_ids),
            reachable,
        )
        if choice is None:
            return None
        return next(b for b in blocks.blocks if b.id == choice.id)

    def _send_pick_place(self, goal: PickAndPlace.Goal):
        timeout = self.timeouts.action_s
        if not self.pick_place.wait_for_server(timeout_sec=self.timeouts.service_s):
            raise TimeoutError("action pick_and_place is not available")
        handle = wait_future(
            self.pick_place.send_goal_async(goal), self.timeouts.service_s, "pick_and_place goal"
        )
        if not handle.accepted:
            raise ExperimentAborted("pick_and_place rejected the goal")
        try:
            return wait_future(handle.get_result_async(), timeout, "pick_and_place result").result
        except TimeoutError:
            handle.cancel_goal_async()
            raise

    def pick_reachable(self, x: float, y: float, level: int) -> bool:
        """Within the annulus, and within the top-down reach for a block at that level."""
        low, high = self.reach
        if self.reach_by_level:
            high = min(high, self.reach_by_level[min(max(level, 1), len(self.reach_by_level)) - 1])
        return low <= math.hypot(x, y) <= high

    # -- resets --------------------------------------------------------------------------

    def blocks_out_of_reach(self) -> list[str]:
        blocks = self.blocks()
        if blocks is None:
            return []
        low, high = self.reach
        return [
            b.id
            for b in blocks.blocks
            if b.on_top and not low <= math.hypot(b.pose.position.x, b.pose.position.y) <= high
        ]

    def reset(self, seed: int = -1) -> str:
        response = call_service(
            self.reset_client, ResetWorld.Request(seed=seed), self.timeouts.service_s
        )
        if not response.success:
            raise ExperimentAborted(f"reset_world: {response.message}")
        return response.message
