"""The explorer's environment on the arm, over ROS 2: fovea services, pick-and-place, judge.

Runs on the curiosity node's experiment thread. Every call waits on a future with a bounded
wait (katana_common.futures) while the node's executor spins elsewhere, and every wait ends at
once when the node stops. Configuration comes in as `EnvironmentConfig`; nothing here reads a
node parameter.
"""

from __future__ import annotations

import copy
import math
import threading
import time
from dataclasses import dataclass, replace

import numpy as np
from action_msgs.msg import GoalStatus
from builtin_interfaces.msg import Time
from katana_common.action_client import ActionClient
from katana_common.futures import Stopped, wait_for_future
from katana_common.messages import to_nanoseconds
from katana_common.qos import JOINT_STATE_QOS, STATE_QOS
from katana_description.models import stands_upright
from katana_interfaces.action import PickAndPlace
from katana_interfaces.msg import BlockArray, FoveaInstance
from katana_interfaces.srv import FindPlacement, JudgePlacement, ObserveSetting, ResetWorld
from rclpy.node import Node
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool

from .core.block_choice import BlockView, PickReach, choose_block_to_move, movable_count
from .core.environment import Outcome, Setting
from .core.explorer import Choice
from .core.robot_loop import (
    ARM_MOVED_RESULTS,
    GIVE_UP,
    UNREALISABLE,
    ExecutionRecord,
    ExperimentAborted,
    Stopping,
    Unrealisable,
    after_failed_pick_place,
    leave_until_moved,
)
from .core.run_record import InstanceRecord
from .core.skill import choose_base, outside_band_m, reach_band

#: block memory's output: the blocks it knows, with levels and poses
BLOCKS_TOPIC = "memory/blocks"
RESET_TYPE = "katana_interfaces/srv/ResetWorld"
#: std_msgs/Bool, transient-local: true while the arm is connected and calibrated (driver)
ARM_READY_TOPIC = "arm_ready"
_RESULT = PickAndPlace.Result


@dataclass(frozen=True)
class EnvironmentConfig:
    """What RobotEnvironment needs; node_params.environment_config builds it from a node's
    parameters (their defaults are the parameters', stated there once)."""

    n_actions: int
    max_height: int
    grasp_retries: int
    reach: PickReach
    service_timeout_s: float
    action_timeout_s: float
    blocks_timeout_s: float
    reset_service: str  # "": the one ResetWorld service the backend offers
    place_reach_m: tuple[tuple[float, float], ...] = ()  # (near, far) radius per height, m


class RobotEnvironment:
    """Environment (core.environment) and RobotEnvironment (core.robot_loop) on the graph."""

    def __init__(self, node: Node, config: EnvironmentConfig, stop: threading.Event,
                 callback_group=None) -> None:
        self.node, self.config, self.stop = node, config, stop
        kw = {"callback_group": callback_group}
        self.observe_client = node.create_client(ObserveSetting, "fovea/observe", **kw)
        self.find_client = node.create_client(FindPlacement, "fovea/find_placement", **kw)
        self.judge_client = node.create_client(JudgePlacement, "perception/judge_placement", **kw)
        self.pick_place = ActionClient(node, PickAndPlace, "pick_and_place", **kw)
        self.reset_client = None
        self._callback_group = callback_group
        self.observed_blocks: BlockArray | None = None
        self._cv = threading.Condition()
        self._blocks: BlockArray | None = None
        self._blocks_count = 0
        self._count_at_done: int | None = None
        self._done_ns = 0
        self._experience: int | None = None  # the last experience out, awaited from the memory
        self._reset_stamp_ns: int | None = None  # the last reset's scene stood from (camera time)
        self._arm_reset = Time()  # ... and its arm's: each pick-and-place plans from joints since
        self._stood_ns: int | None = None  # ... as awaited after the scene change it caused
        self._joint_states = 0
        self._arm_ready: bool | None = None  # the driver's arm_ready; None: none heard yet
        node.create_subscription(BlockArray, BLOCKS_TOPIC, self.on_blocks, STATE_QOS, **kw)
        # only to see the arm publish (readiness): dropped once the graph is ready, so the
        # node does not take every joint state of the run for nothing
        self._joint_state_sub = node.create_subscription(
            JointState, "joint_states", self._on_joint_state, JOINT_STATE_QOS, **kw)
        node.create_subscription(Bool, ARM_READY_TOPIC, self._on_arm_ready, STATE_QOS, **kw)
        self.instances: list[FoveaInstance] = []
        self.offered_instances: list[FoveaInstance] = []
        #: the paper's setting counter i: settings observed in this run (resumes set it)
        self.settings_observed = 0
        self.observe_s = 0.0
        # blocks the arm could not pick, with where they were: skipped until they move
        self.unpickable: dict[str, tuple[float, float]] = {}

    # -- subscriptions -------------------------------------------------------------------

    def on_blocks(self, msg: BlockArray) -> None:
        with self._cv:
            self._blocks = msg
            self._blocks_count += 1
            self._cv.notify_all()

    def _on_arm_ready(self, msg: Bool) -> None:
        with self._cv:
            self._arm_ready = bool(msg.data)
            self._cv.notify_all()

    def _on_joint_state(self, _msg: JointState) -> None:
        with self._cv:
            self._joint_states += 1
            self._cv.notify_all()

    def _wait(self, condition, timeout_s: float, what: str) -> None:
        """Wait on the condition variable until `condition()`; Stopping / TimeoutError."""
        deadline = time.monotonic() + timeout_s
        with self._cv:
            while not condition():
                if self.stop.is_set():
                    raise Stopping(f"stopped while waiting for {what}")
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"no {what} within {timeout_s:.1f} s")
                self._cv.wait(min(left, 0.05))

    def wait_for_blocks(self, newer_than: int | None = None) -> BlockArray:
        """The latest memory/blocks, or the first one after message number `newer_than`."""
        self._wait(lambda: self._blocks is not None and (
            newer_than is None or self._blocks_count > newer_than),
            self.config.blocks_timeout_s, f"fresh {BLOCKS_TOPIC}")
        return self._blocks

    def wait_for_scene_after(self, parked_ns: int) -> BlockArray:
        """The first memory/blocks built from an image taken after the arm parked (at
        `parked_ns` on this node's clock), with the memory at rest on it, so the judge sees the
        outcome, as the paper's robot did: one whose stamp (its image's time) is at or past
        `parked_ns`, or the second one from now (one may come from an image captured during the
        last motion, the second cannot), whichever comes first, and with a settled frame (one
        located on levels it changed none of). The stamp rule needs the node's clock to be the
        camera's. In the fast sim it is an ordering, not a race: no image is rendered while a
        motion is stepped, and /clock went out during the last motion and at its end before
        its result, so an image stamped at or past `parked_ns` was rendered after the arm
        stopped.

        The settled frame makes the experience that follows reach a memory at rest: one whose
        first frame of the new scene changed a level locates on the new levels once more
        (perception segments the latest image again), and an experience that came between the
        two would be folded into another history than one that came after them (seen: a
        memory that took the experience first located a fallen block 1.3 px elsewhere, and the
        run parted from there)."""
        newer_than = self.blocks_count() + 1
        self._wait(lambda: (self._blocks_count > newer_than or (
            self._blocks_count > newer_than - 1 and _stamp_ns(self._blocks) >= parked_ns))
            and self._blocks.settled_frames > 0,
            self.config.blocks_timeout_s, f"{BLOCKS_TOPIC} after the arm parked")
        return self._blocks

    def blocks_count(self) -> int:
        with self._cv:
            return self._blocks_count

    # -- readiness -----------------------------------------------------------------------

    def wait_until_ready(self, timeout_s: float, log_every_s: float = 5.0) -> None:
        """Until the arm is ready (its arm_ready is true where a backend publishes one, as the
        driver does once connected and calibrated; else joint_states arrive), the action and
        services answer and the memory has published. Logged while waiting; TimeoutError
        after `timeout_s`."""
        deadline = time.monotonic() + timeout_s
        logger = self.node.get_logger()
        while True:
            missing = self._missing()
            if not missing:
                if self._joint_state_sub is not None:
                    self.node.destroy_subscription(self._joint_state_sub)
                    self._joint_state_sub = None
                return
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"the graph is not ready after {timeout_s:.1f} s: still "
                                   f"waiting for {', '.join(missing)}")
            logger.info(f"waiting for {', '.join(missing)} ({left:.0f} s left)",
                        throttle_duration_sec=log_every_s)
            if self.stop.wait(min(0.1, left)):
                raise Stopping("stopped while waiting for the graph")

    def _missing(self) -> list[str]:
        missing = []
        with self._cv:
            if not self._joint_states:
                missing.append("joint_states")
            if self._blocks is None:
                missing.append(BLOCKS_TOPIC)
            arm_ready = self._arm_ready
        if arm_ready is not True and (
                arm_ready is False or self.node.count_publishers(ARM_READY_TOPIC) > 0):
            missing.append(f"{ARM_READY_TOPIC} (the driver connected and calibrated)")
        if not self.pick_place.server_is_ready():
            missing.append("action pick_and_place")
        for client in (self.observe_client, self.find_client, self.judge_client):
            if not client.service_is_ready():
                missing.append(f"service {client.srv_name}")
        if self._reset() is None:
            found = self._reset_candidates()
            missing.append("a ResetWorld service" if len(found) < 2 else
                           f"one ResetWorld service, not {len(found)} ({', '.join(found)}): "
                           "set reset_service")
        return missing

    def _reset_candidates(self) -> list[str]:
        return sorted(n for n, types in self.node.get_service_names_and_types()
                      if RESET_TYPE in types)

    def _reset(self):
        """The reset client: the configured name, or the backend's one ResetWorld service."""
        if self.reset_client is None:
            name = self.config.reset_service
            if not name:
                found = self._reset_candidates()
                if len(found) != 1:
                    return None
                name = found[0]
            self.reset_client = self.node.create_client(
                ResetWorld, name, callback_group=self._callback_group)
        return self.reset_client if self.reset_client.service_is_ready() else None

    # -- the protocol --------------------------------------------------------------------

    def wait_until_current(self) -> None:
        """Until the memory has taken the last experiment in and seen an image after it.

        The memory answers an experience at once (placing the moved block where it was put)
        and refines that pose from the next image; the fovea builds its scene from whichever
        it has when asked. After an experience this waits for a memory/blocks that names it as
        handled with a settled frame after it (one located on the levels the experience left,
        which changed none of them: the memory is at rest until the scene changes): an exact
        ordering, whatever the thread timing. After a reset whose answer said from when the new
        scene stood, it waits for a message built from an image stamped at or after that, with
        a settled frame: exact too. After another scene change without an experience (a skill
        attempt, a backend that gives no stamp) it waits for a message stamped
        `_STAMP_MARGIN_NS` past the change (or, if the stamps are on another clock, the fourth).
        """
        if self._experience is not None:
            index = self._experience
            try:
                self._wait(lambda: self._blocks is not None and (
                    self._blocks.experience > index or (
                        self._blocks.experience == index
                        and self._blocks.settled_frames > 0)),
                    self.config.blocks_timeout_s, f"{BLOCKS_TOPIC} after experience {index}")
            except TimeoutError:
                self._experience = None  # a memory that does not echo: by the stamps next time
                raise
            return
        if self._count_at_done is None:
            self.wait_for_blocks()
            return
        if self._stood_ns is not None:
            stood = self._stood_ns
            self._wait(lambda: self._blocks is not None and _stamp_ns(self._blocks) >= stood
                       and self._blocks.settled_frames > 0,
                       self.config.blocks_timeout_s, f"{BLOCKS_TOPIC} of the reset scene")
            return
        count, after = self._count_at_done, self._done_ns + _STAMP_MARGIN_NS
        self._wait(lambda: self._blocks_count > count + 1 and (
            _stamp_ns(self._blocks) >= after or self._blocks_count > count + 3),
            self.config.blocks_timeout_s, f"{BLOCKS_TOPIC} after the scene changed")

    def mark_scene_changed(self, experience: int | None = None,
                           parked_ns: int | None = None) -> None:
        """`experience`: the index of the experience about to go out on curiosity/experience
        (the memory echoes it); None: the scene changed without one (after `reset`, from the
        time its answer gave; after a failed pick-and-place, from `parked_ns`, when the arm
        had parked on this node's clock, which must be the camera's, as for
        wait_for_scene_after)."""
        self._experience = experience
        self._count_at_done = self.blocks_count()
        self._done_ns = self.node.get_clock().now().nanoseconds
        stood = self._reset_stamp_ns if parked_ns is None else parked_ns
        self._stood_ns = stood if experience is None else None
        self._reset_stamp_ns = None

    def observe(self) -> Setting:
        start = time.perf_counter()
        # the fovea answers from this memory/blocks or a later one, never from one before it
        blocks = self.wait_for_blocks()
        request = ObserveSetting.Request(max_height=self.config.max_height,
                                         blocks_sequence=blocks.sequence)
        self.settings_observed += 1
        response = self._call(self.observe_client, request)
        self.observe_s = time.perf_counter() - start
        if not response.success:
            raise Unrealisable("fovea_failed", f"fovea/observe: {response.message}")
        usable = [inst for inst in response.instances
                  if 0 <= inst.state <= self.config.max_height
                  and 1 <= inst.action <= self.config.n_actions]
        # Available means executable (paper 2.2: availability comes from the known blocks): a
        # placement needs a block the arm can pick that is not part of the target stack.
        self.observed_blocks = blocks
        usable = [inst for inst in usable if self._choose_block(blocks, inst, set())]
        if not usable:
            raise Unrealisable("no_usable_instance",
                               "fovea/observe listed no instance with a block to move")
        self.instances = usable
        self.offered_instances = list(usable)  # as the fovea offered them, unturned
        states = np.array([inst.state for inst in usable])
        actions = np.array([inst.action - 1 for inst in usable])
        return Setting.from_pairs(states, actions)

    def place_planned(self, setting: Setting, choice: Choice, target_height: int,
                      turn_rad: float = 0.0) -> Choice:
        """Which instance of a planned pair to make: the first whose block, once placed, lies
        within the place reach of every height from the stack it makes up to `target_height`
        (core.skill.choose_base on the narrowest band), so that a stack grows where the height
        the plan builds towards can be reached. The block is placed turned by `turn_rad`
        against the fovea (the block below) when it is not 0 (`core.robot_loop.build_turn`)."""
        choice = within_reach(setting, choice, target_height, self.instances,
                              self.config.place_reach_m, self.config.max_height)
        if choice.index is not None:
            offered = self.offered_instances[choice.index]
            self.instances[choice.index] = turned(offered, turn_rad) if turn_rad else offered
        return choice

    def out_of_reach_for(self, choice: Choice, target_height: int) -> bool:
        """Whether the placement chosen for `choice` (`place_planned`) makes a stack on which
        the heights up to `target_height` cannot be placed (`leaves_goal_out_of_reach`)."""
        if choice.index is None:
            return False
        return leaves_goal_out_of_reach(self.instances[choice.index], choice.state,
                                        target_height, self.config.place_reach_m)

    def moves_a_loose_block(self, choice: Choice) -> bool:
        """Whether a placement on the table would move a block that lies on the table itself
        (no stack's top can be taken): that leaves every stack as it was."""
        if choice.state != 0 or choice.index is None or self.observed_blocks is None:
            return False
        block = self._choose_block(self.observed_blocks, self.instances[choice.index], set())
        return block is not None and block.level == 1

    def movable_blocks(self) -> int:
        """How many blocks of the last observed setting the arm could move (upright, on top,
        within reach): what a stack can still be built with."""
        if self.observed_blocks is None:
            return 0
        return movable_count(self._views(self.observed_blocks, set()), self._can_pick)

    def stack_heights(self) -> tuple[int, ...]:
        """The heights of the stacks in the last observed setting (a loose block is a stack of
        one), from the same memory/blocks the offer was made from."""
        if self.observed_blocks is None:
            return ()
        return tuple(sorted(b.level for b in self.observed_blocks.blocks if b.on_top))

    def execute(self, state: int, action: int, index: int | None = None) -> Outcome:
        stages: dict[str, float] = {"observe_s": self.observe_s}
        t = time.perf_counter()
        instance = self.instances[index] if index is not None else self._find(state, action)
        stages["find_s"] = time.perf_counter() - t
        if self._choose_block(self.wait_for_blocks(), instance, set()) is None:
            # before anything is judged or moved, so that a planner tries its next choice
            raise Unrealisable("no_block_to_move",
                               "no accessible block to move for this placement")

        t = time.perf_counter()
        self._judge(JudgePlacement.Request.PHASE_BEFORE, instance, "")
        stages["judge_before_s"] = time.perf_counter() - t

        t = time.perf_counter()
        moved, attempts = self._pick_and_place(instance)
        stages["pick_place_s"] = time.perf_counter() - t

        t = time.perf_counter()
        self.wait_for_scene_after(self.node.get_clock().now().nanoseconds)
        stages["settle_s"] = time.perf_counter() - t

        t = time.perf_counter()
        label = self._judge(JudgePlacement.Request.PHASE_AFTER, instance, moved)
        stages["judge_s"] = time.perf_counter() - t
        if label not in (-1, 1):
            raise ExperimentAborted("no_verdict", f"the judge gave no verdict (label {label})")
        available = sorted({int(i.state) for i in self.instances})
        offered = self.offered_instances[index] if index is not None else None
        record = ExecutionRecord(_instance_record(instance, offered), self.settings_observed,
                                 available, moved, attempts, stages, instance, index)
        return Outcome(label, record)

    # -- steps ---------------------------------------------------------------------------

    def _call(self, client, request):
        timeout = self.config.service_timeout_s
        self._await_server(client.service_is_ready, f"service {client.srv_name}")
        try:
            return wait_for_future(client.call_async(request), timeout,
                                   f"service {client.srv_name}", stop=self.stop)
        except Stopped as exc:
            raise Stopping(str(exc)) from None

    def _await_server(self, is_ready, what: str) -> None:
        """Until `is_ready()`; TimeoutError after service_timeout_s, Stopping on stop."""
        deadline = time.monotonic() + self.config.service_timeout_s
        while not is_ready():
            if time.monotonic() > deadline:
                raise TimeoutError(f"{what} is not available")
            if self.stop.wait(0.02):
                raise Stopping(f"stopped while waiting for {what}")

    def _find(self, state: int, action: int) -> FoveaInstance:
        # plain ints: the generated C conversion aborts the process on a numpy integer
        request = FindPlacement.Request(state=int(state), action=int(action) + 1,
                                        blocks_sequence=self.wait_for_blocks().sequence)
        response = self._call(self.find_client, request)
        if not response.found:
            raise Unrealisable("no_placement", f"no fovea location realises (s={state}, "
                               f"a={action + 1}): {response.message}")
        return response.instance

    def _judge(self, phase: int, instance: FoveaInstance, placed: str) -> int:
        # judged against the memory this node acted on (or a later one), not the one the
        # perception happens to hold
        with self._cv:
            sequence = self._blocks.sequence if self._blocks is not None else 0
        request = JudgePlacement.Request(phase=phase, instance=instance, placed_block=placed,
                                         blocks_sequence=sequence)
        response = self._call(self.judge_client, request)
        if not response.success:
            raise ExperimentAborted("judge_failed",
                                    f"perception/judge_placement: {response.message}")
        return int(response.label)

    def _pick_and_place(self, instance: FoveaInstance) -> tuple[str, int]:
        """Move the chosen block; a missed grasp is retried (the paper resets and tries again)."""
        excluded: set[str] = set()
        attempts = 0
        while True:
            attempts += 1
            block = self._choose_block(self.wait_for_blocks(), instance, excluded)
            if block is None:
                raise Unrealisable("no_block_to_move",
                                   "no accessible block to move for this placement")
            goal = PickAndPlace.Goal(block_id=block.id, pick=block.pose, block_size=block.size,
                                     place=instance.placement,
                                     joint_states_after=self._arm_reset)
            result = self._send_pick_place(goal)
            if result.success:
                return block.id, attempts
            name = _code_name(result.error_code)
            if name in ARM_MOVED_RESULTS:
                # what the memory shows next (a retry's block, the next experiment's setting)
                # must come from an image taken after the arm parked, not whichever it had (a
                # memory that stamps nothing: by the count, as after a stampless reset)
                stamped = self._blocks is not None and _stamp_ns(self._blocks) > 0
                self.mark_scene_changed(
                    parked_ns=self.node.get_clock().now().nanoseconds if stamped else None)
                self.wait_until_current()
            reason = f"pick_and_place of {block.id}: {result.message} ({name})"
            action = after_failed_pick_place(name, attempts, self.config.grasp_retries)
            if action == UNREALISABLE:
                raise Unrealisable(name, reason)
            if leave_until_moved(name, action):
                self.unpickable[block.id] = (block.pose.position.x, block.pose.position.y)
                excluded.add(block.id)
            if action == GIVE_UP:
                raise ExperimentAborted(name, f"{reason}; gave up after {attempts} attempts")
            self.node.get_logger().warning(f"{reason}; retrying")

    def _still_unpickable(self, block) -> bool:
        where = self.unpickable.get(block.id)
        if where is None:
            return False
        if np.hypot(block.pose.position.x - where[0], block.pose.position.y - where[1]) < 0.005:
            return True
        del self.unpickable[block.id]  # it moved: worth trying again
        return False

    def _views(self, blocks: BlockArray, excluded: set[str]) -> list[BlockView]:
        return [BlockView(b.id, b.pose.position.x, b.pose.position.y, b.on_top, b.level,
                          b.resting_pose_known
                          and stands_upright((b.size.x, b.size.y, b.size.z)))
                for b in blocks.blocks if b.id not in excluded and not self._still_unpickable(b)]

    def _can_pick(self, view: BlockView) -> bool:
        return self.config.reach.can_pick(view.x, view.y, view.level)

    def _choose_block(self, blocks: BlockArray, instance: FoveaInstance, excluded: set[str]):
        choice = choose_block_to_move(
            self._views(blocks, excluded),
            (instance.placement.position.x, instance.placement.position.y),
            list(instance.support_ids), self._can_pick, from_stacks_first=instance.state == 0)
        if choice is None:
            return None
        return next(b for b in blocks.blocks if b.id == choice.id)

    def _send_pick_place(self, goal: PickAndPlace.Goal):
        timeout = self.config.service_timeout_s
        self._await_server(self.pick_place.server_is_ready, "action pick_and_place")
        try:
            handle = wait_for_future(self.pick_place.send_goal_async(goal), timeout,
                                     "pick_and_place goal", stop=self.stop)
            if not handle.accepted:
                raise ExperimentAborted("goal_rejected", "pick_and_place rejected the goal")
            try:
                answer = wait_for_future(handle.get_result_async(), self.config.action_timeout_s,
                                         "pick_and_place result", stop=self.stop)
            except (TimeoutError, Stopped):
                _cancel(handle)  # the executor stops the arm on a cancel
                raise
        except Stopped as exc:
            raise Stopping(str(exc)) from None
        if answer.status not in (GoalStatus.STATUS_SUCCEEDED, GoalStatus.STATUS_ABORTED):
            raise ExperimentAborted("goal_" + _status_name(answer.status),
                                    f"pick_and_place ended with status "
                                    f"{_status_name(answer.status)}: {answer.result.message}")
        return answer.result

    # -- resets --------------------------------------------------------------------------

    def blocks_out_of_reach(self) -> list[str]:
        with self._cv:
            blocks = self._blocks
        if blocks is None:
            return []
        reach = self.config.reach
        return [b.id for b in blocks.blocks
                if b.on_top and not reach.within_play_area(b.pose.position.x, b.pose.position.y)]

    def reset(self, seed: int = -1) -> str:
        """Reset the world; the next `mark_scene_changed()` waits for the new scene from the
        time the backend says it stood (ResetWorld's stamp), if it says."""
        client = self._reset()
        if client is None:
            raise TimeoutError("no ResetWorld service is available")
        response = self._call(client, ResetWorld.Request(seed=seed))
        if not response.success:
            raise ExperimentAborted("reset_failed", f"reset_world: {response.message}")
        self._reset_stamp_ns = to_nanoseconds(response.stamp) or None
        self._arm_reset = copy.copy(response.stamp)
        return response.message


#: after a scene change without an experience (a reset, a skill attempt): how far the node's
#: clock may lag the camera's, ns. An image rendered before the change but stamped past the
#: node's clock then would be taken as after it. Experiences and parking need no margin (see
#: wait_until_current, wait_for_scene_after).
_STAMP_MARGIN_NS = 100_000_000


def _stamp_ns(msg: BlockArray) -> int:
    return to_nanoseconds(msg.header.stamp)


def _cancel(handle) -> None:
    """Ask the executor to stop the goal; at shutdown the context may be gone already."""
    try:
        handle.cancel_goal_async()
    except Exception:  # noqa: BLE001 - nothing more can be done for a goal of a dead graph
        pass


def within_reach(setting: Setting, choice: Choice, target_height: int,
                 instances: list[FoveaInstance], place_reach_m, max_height: int) -> Choice:
    """`choice` made at the first of its instances whose block, once placed, lies within the
    place reach of every height from the stack it makes up to `target_height` (choose_base on
    the narrowest band)."""
    hits = setting.indices_of(choice.state, choice.action)
    if len(hits) < 2 or not place_reach_m:
        return choice
    where = [(instances[i].placement.position.x, instances[i].placement.position.y)
             for i in hits]
    made = choice.state + 1
    reach = list(place_reach_m)
    band = reach_band(made, target_height, reach)
    if band is not None:
        reach[made] = band
    best = hits[choose_base(where, choice.state, max_height + 1, tuple(reach))]
    return replace(choice, index=int(best))


def leaves_goal_out_of_reach(instance: FoveaInstance, state: int, target_height: int,
                             place_reach_m) -> bool:
    """Whether the block of a placement on a stack of height `state` at `instance`, once
    placed, lies where no block can be placed on the stack it makes at some height up to
    `target_height` (outside the narrowest of those place reach bands): the fovea offers no
    pair on such a stack, so a plan through it cannot reach its goal."""
    band = reach_band(state + 1, target_height, list(place_reach_m)) if place_reach_m else None
    if band is None or target_height <= state:
        return False
    position = instance.placement.position
    return outside_band_m((position.x, position.y), band) > 0.0


def turned(instance: FoveaInstance, turn_rad: float) -> FoveaInstance:
    """A copy of `instance` whose block is placed turned by `turn_rad` about the vertical."""
    out = copy.deepcopy(instance)
    q = instance.placement.orientation
    rotation = Rotation.from_euler("z", turn_rad) * Rotation.from_quat([q.x, q.y, q.z, q.w])
    o = out.placement.orientation
    o.x, o.y, o.z, o.w = (float(v) for v in rotation.as_quat())
    return out


def _yaw(pose) -> float:
    q = pose.orientation
    return float(Rotation.from_quat([q.x, q.y, q.z, q.w]).as_euler("zyx")[0])


def _instance_record(inst: FoveaInstance, offered: FoveaInstance | None = None) -> InstanceRecord:
    """The record of an executed instance; `offered`: as the fovea offered it (the turn is the
    difference of the two placements' yaws)."""
    p = inst.placement.position
    turn = 0.0
    if offered is not None and offered is not inst:
        turn = math.remainder(_yaw(inst.placement) - _yaw(offered.placement), 2 * math.pi)
    return InstanceRecord(float(inst.pixel_u), float(inst.pixel_v), [bool(b) for b in inst.bits],
                          [float(v) for v in inst.features], [str(s) for s in inst.support_ids],
                          [float(p.x), float(p.y), float(p.z)], turn)


_CODE_NAMES = {getattr(_RESULT, n): n.lower() for n in dir(_RESULT)
               if n.isupper() and isinstance(getattr(_RESULT, n), int)}
_STATUS_NAMES = {getattr(GoalStatus, n): n.removeprefix("STATUS_").lower() for n in dir(GoalStatus)
                 if n.startswith("STATUS_")}


def _code_name(code: int) -> str:
    return _CODE_NAMES.get(int(code), f"code_{int(code)}")


def _status_name(status: int) -> str:
    return _STATUS_NAMES.get(int(status), f"status_{int(status)}")
