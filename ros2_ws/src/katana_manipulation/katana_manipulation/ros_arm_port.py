"""RosArmPort: the pick-and-place sequence's arm port (core.pick_place.ArmPort) over the arm and
gripper actions and joint_states of a PickPlaceExecutor node. Every wait is bounded in wall time
and ends at once when the node stops (katana_common.futures)."""

from __future__ import annotations

import time

from action_msgs.msg import GoalStatus
from control_msgs.action import FollowJointTrajectory, GripperCommand
from control_msgs.msg import JointTolerance
from katana_common.action_client import ActionClient
from katana_common.futures import Stopped, wait_for_future
from katana_common.messages import duration_msg
from katana_description import arm_contract as ac
from katana_description import models as m
from trajectory_msgs.msg import JointTrajectoryPoint

from katana_manipulation.core import pick_place as pp

ARM_ACTION = "arm_controller/follow_joint_trajectory"
GRIPPER_ACTION = "gripper_controller/gripper_command"
#: a task waits at most this long (wall time) for joint_states that show the arm holding where
#: the last task left it (RosArmPort.settled)
SETTLE_WAIT_S = 1.0


class RosArmPort:
    """pp.ArmPort over the arm and gripper actions; every call returns within its bound."""

    def __init__(self, node) -> None:
        self.node = node
        self.commanded: list[float] | None = None  # last arm pose a move succeeded to
        self.gripped: float | None = None  # where the last gripper goal that succeeded ended

    def _send(self, client: ActionClient, name: str, goal, result_timeout_s: float):
        """(result, '') or (None, why) for a refusal or ("timeout", why) for a wait that ran out.
        Raises Stopped when the node stops."""
        n = self.node
        wait_s = n.params["server_timeout_s"]
        if not client.server_is_ready():
            deadline = time.monotonic() + wait_s
            while not client.server_is_ready():
                if n.stopping.wait(0.02) or time.monotonic() > deadline:
                    if n.stopping.is_set():
                        raise Stopped(f"{name}: stopped")
                    return "timeout", f"action server {name} not available"
        try:
            handle = wait_for_future(client.send_goal_async(goal), wait_s, name, n.stopping)
        except TimeoutError:
            return "timeout", f"{name}: no answer to the goal"
        if handle is None or not handle.accepted:
            return None, f"{name}: goal rejected"
        try:
            return wait_for_future(handle.get_result_async(), result_timeout_s, name,
                                   n.stopping), ""
        except (TimeoutError, Stopped) as exc:
            handle.cancel_goal_async()
            if isinstance(exc, Stopped):
                raise
            return "timeout", f"{name}: no result within {result_timeout_s:.1f} s"

    def _timeout_s(self, planned_s: float) -> float:
        return planned_s * self.node.params["time_scale"] + self.node.params["timeout_margin_s"]

    def move(self, points: list[list[float]], times: list[float],
             velocities: list[list[float]] | None = None,
             finger_tolerance: float | None = None,
             finger_goal_tolerance: float | None = None) -> pp.MoveResult:
        goal = FollowJointTrajectory.Goal()
        goal.trajectory.joint_names = list(m.ARM_JOINTS)
        if finger_tolerance is not None:
            goal.path_tolerance = [JointTolerance(name=n, position=float(finger_tolerance))
                                   for n in m.FINGER_JOINTS]
        if finger_goal_tolerance is not None:
            goal.goal_tolerance = [JointTolerance(name=n, position=float(finger_goal_tolerance))
                                   for n in m.FINGER_JOINTS]
        vels = velocities or [[] for _ in points]
        goal.trajectory.points = [
            JointTrajectoryPoint(positions=list(q), velocities=list(v),
                                 time_from_start=duration_msg(t))
            for q, v, t in zip(points, vels, times, strict=True)
        ]
        self.commanded = None  # until this move has succeeded
        res, why = self._send(self.node.arm_client, ARM_ACTION, goal, self._timeout_s(times[-1]))
        if res is None or res == "timeout":
            return pp.MoveResult(False, why, timed_out=res == "timeout")
        code, text = res.result.error_code, res.result.error_string
        if code != FollowJointTrajectory.Result.SUCCESSFUL:
            return pp.MoveResult(False, text or f"error code {code}",
                                 fingers_moved=ac.fingers_moved(code, text))
        self.commanded = [float(v) for v in points[-1]]
        return pp.MoveResult(True)

    def grip(self, position: float, effort: float) -> pp.GripResult:
        goal = GripperCommand.Goal()
        goal.command.position = float(position)
        goal.command.max_effort = float(effort)
        self.gripped = None  # until this goal has succeeded
        res, why = self._send(self.node.gripper_client, GRIPPER_ACTION, goal, self._timeout_s(3.0))
        if res is None or res == "timeout":
            return pp.GripResult(False, message=why, timed_out=res == "timeout")
        r = res.result
        ok = res.status == GoalStatus.STATUS_SUCCEEDED
        self.gripped = float(r.position) if ok else None
        return pp.GripResult(ok, r.position, r.stalled, r.reached_goal,
                             "" if ok else f"gripper goal ended with status {res.status}")

    def settled(self, timeout_s: float = SETTLE_WAIT_S) -> bool:
        """Wait (bounded) until joint_states show the arm where the last move that succeeded
        sent it and the fingers where the last gripper goal that succeeded left them
        (pick_place.holds_where_sent). A task starts from what joint_states say, and one taken
        late, from before the last motion ended, would change its plan and whether it opens
        the fingers first: runs would follow the callbacks' timing. False when the bound ran
        out (the arm is elsewhere: the task starts from where it is) or the node stops."""
        if self.commanded is None and self.gripped is None:
            return True  # nothing known to hold
        return self._latest_when(
            lambda joints, _ns: pp.holds_where_sent(joints, self.commanded, self.gripped),
            timeout_s) is not None

    def joint_positions(self, stamped_after_ns: int = 0) -> dict[str, float] | None:
        """The latest joint positions, once a joint_states stamped at or after
        `stamped_after_ns` has come; None after server_timeout_s or when the node stops."""
        return self._latest_when(lambda _joints, ns: ns >= stamped_after_ns,
                                 self.node.params["server_timeout_s"])

    def _latest_when(self, accept, timeout_s: float) -> dict[str, float] | None:
        """The latest joint positions once ``accept(joints, stamp_ns)`` holds for them; None
        after ``timeout_s`` (wall time) or when the node stops."""
        n = self.node
        deadline = time.monotonic() + timeout_s
        while not n.stopping.is_set():
            with n.state_lock:
                latest, stamp_ns = n.latest_joints, n.latest_joints_ns
            if latest is not None and accept(latest, stamp_ns):
                return dict(latest)
            if time.monotonic() >= deadline:
                return None
            n.stopping.wait(0.01)
        return None
