"""An ArmPort that drives a katana_sim SimWorld directly, without ROS: steps the world until each
motion is done (bounded by simulated time). For tests, benchmarks and scripted experiments."""

from __future__ import annotations

from katana_description import models as m

from katana_manipulation.core.pick_place import GripResult, MoveResult


class WorldPort:
    def __init__(self, world, slack: float = 3.0, steps_per_check: int = 12) -> None:
        self.world = world
        self.slack = slack  # simulated seconds a motion may overrun its plan
        self.steps = steps_per_check

    def _run(self, handle, budget: float):
        end = self.world.time + budget
        while not handle.outcome.done and self.world.time < end:
            self.world.step(self.steps)
        return handle.outcome

    def move(self, points: list[list[float]], times: list[float],
             velocities: list[list[float]] | None = None) -> MoveResult:
        from katana_sim.core import TrajectoryGoal

        handle = self.world.start_trajectory(
            TrajectoryGoal(list(m.ARM_JOINTS), times, points, velocities))
        out = self._run(handle, times[-1] + self.slack)
        if not out.done:
            self.world.cancel_trajectory("timeout")
            return MoveResult(False, "no outcome in time", timed_out=True)
        return MoveResult(out.status == "succeeded", out.message)

    def grip(self, position: float, effort: float) -> GripResult:
        handle = self.world.start_gripper(position, effort)
        out = self._run(handle, 2.0 + self.slack)
        if not out.done:
            self.world.cancel_gripper()
            return GripResult(False, message="no outcome in time", timed_out=True)
        return GripResult(out.status == "succeeded", out.position, out.stalled, out.reached_goal,
                          out.message)

    def joint_positions(self) -> dict[str, float] | None:
        return self.world.joint_positions()
