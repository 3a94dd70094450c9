"""An ArmPort (katana_manipulation.core.pick_place) that drives a katana_sim PhysicsSim directly,
without ROS: each motion is lock-stepped to its end exactly as sim_node's fast mode does it
(`katana_sim.core.pacing.run_motion`). For tests and for bench_arm's physics-only floor."""

from __future__ import annotations

from contextlib import nullcontext

from katana_description import arm_contract as ac
from katana_description import models as m
from katana_manipulation.core.pick_place import GripResult, MoveResult
from katana_sim.core import TrajectoryGoal
from katana_sim.core.pacing import DONE, run_motion


class PhysicsPort:
    def __init__(self, sim, slack_s: float = 3.0) -> None:
        self.sim = sim
        self.slack_s = slack_s  # simulated seconds a motion may overrun its plan
        self.commanded: list[float] | None = None  # as RosArmPort: the last pose moved to
        self.gripped: float | None = None  # as RosArmPort: where the last grip ended

    def move(self, points: list[list[float]], times: list[float],
             velocities: list[list[float]] | None = None,
             finger_tolerance: float | None = None,
             finger_goal_tolerance: float | None = None) -> MoveResult:
        def on_fingers(tolerance: float | None) -> dict[str, float]:
            return {} if tolerance is None else dict.fromkeys(m.FINGER_JOINTS, tolerance)

        handle = self.sim.start_trajectory(
            TrajectoryGoal(list(m.ARM_JOINTS), times, points, velocities,
                           path_tolerance=on_fingers(finger_tolerance),
                           goal_tolerance=on_fingers(finger_goal_tolerance)))
        if run_motion(self.sim, handle, nullcontext(), times[-1] + self.slack_s) != DONE:
            self.sim.cancel_trajectory("timeout")
            return MoveResult(False, "no outcome in time", timed_out=True)
        out = handle.outcome
        ok = out.status == ac.SUCCEEDED
        self.commanded = [float(v) for v in points[-1]] if ok else None
        return MoveResult(ok, out.message,
                          fingers_moved=ac.fingers_moved(out.error_code, out.message))

    def grip(self, position: float, effort: float) -> GripResult:
        self.gripped = None
        handle = self.sim.start_gripper(position, effort)
        if run_motion(self.sim, handle, nullcontext(), 2.0 + self.slack_s) != DONE:
            self.sim.cancel_gripper()
            return GripResult(False, message="no outcome in time", timed_out=True)
        out = handle.outcome
        ok = out.status == ac.SUCCEEDED
        self.gripped = float(out.position) if ok else None
        return GripResult(ok, out.position, out.stalled, out.reached_goal, out.message)

    def joint_positions(self) -> dict[str, float] | None:
        return self.sim.joint_positions()
