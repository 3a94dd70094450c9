"""Bounded calls into a running simulated graph, for katana-robot's truth and skill commands:
reset the world, read its ground truth and the block memory, ask the fovea for a placement and
run a pick-and-place."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence

from builtin_interfaces.msg import Time
from katana_bringup.run import default_params_files, load_params
from katana_common.action_client import ActionClient
from katana_common.futures import wait_for_future
from katana_common.messages import to_seconds
from katana_common.qos import STATE_QOS
from katana_description.models import lies_flat
from katana_interfaces.action import PickAndPlace
from katana_interfaces.msg import BlockArray
from katana_interfaces.srv import FindPlacement, ResetWorld

from .robot_truth import TrueBlock


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
        self.node = node
        self.stop = stop or threading.Event()
        self._cv = threading.Condition()
        self.truth, self.truth_count = None, 0
        self.memory, self.memory_count = None, 0
        node.create_subscription(BlockArray, "sim/ground_truth", self._on_truth, STATE_QOS)
        node.create_subscription(BlockArray, "memory/blocks", self._on_memory, STATE_QOS)
        self.reset_client = node.create_client(ResetWorld, "sim_node/reset_world")
        self.arm_reset = Time()  # the last reset's stamp: pick-and-place plans from joints since
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

    def latest_truth(self):
        """The newest sim/ground_truth message."""
        with self._cv:
            return self.truth

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
        return wait_for_future(client.call_async(request), timeout_s, client.srv_name,
                               stop=self.stop)

    def reset(self, seed: int) -> None:
        response = self.call(self.reset_client, ResetWorld.Request(seed=int(seed)))
        if not response.success:
            raise RuntimeError(f"reset_world: {response.message}")
        self.arm_reset = response.stamp
        self.settled()

    def settled(self, min_sim_s: float = 0.6, timeout_s: float = 30.0) -> list[TrueBlock]:
        """Ground truth once the blocks have rested (two messages alike) for `min_sim_s` of sim
        time, and a memory/blocks from an image taken after that (two fresh messages)."""
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
        goal = PickAndPlace.Goal(block_id=block.id, pick=block.pose, block_size=block.size,
                                 place=place_pose, joint_states_after=self.arm_reset)
        handle = wait_for_future(self.pick_place.send_goal_async(goal), 30.0,
                                 "pick_and_place goal", stop=self.stop)
        if not handle.accepted:
            raise RuntimeError("pick_and_place rejected the goal")
        return wait_for_future(handle.get_result_async(), timeout_s, "pick_and_place result",
                               stop=self.stop).result

    def find(self, state: int, action: int):
        return self.call(self.find_client, FindPlacement.Request(state=state, action=action))


def lies_flat_msg(block) -> bool:
    """A ground-truth Block message rests on its top or bottom face."""
    q = block.pose.orientation
    return lies_flat(q.x, q.y, q.z, q.w)


def true_blocks(msg) -> list[TrueBlock]:
    return [TrueBlock(b.id, b.pose.position.x, b.pose.position.y, b.pose.position.z,
                      int(b.level), lies_flat_msg(b))
            for b in msg.blocks]


def _at_rest(a: Sequence, b: Sequence, tol_m: float = 1e-3) -> bool:
    return len(a) == len(b) and all(
        x.id == y.id and abs(x.x - y.x) < tol_m and abs(x.y - y.y) < tol_m
        and abs(x.z - y.z) < tol_m for x, y in zip(a, b, strict=True))
