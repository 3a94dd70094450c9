"""Action messages <-> katana_description.arm_contract goals and outcomes, for the node."""

from __future__ import annotations

from control_msgs.action import FollowJointTrajectory, GripperCommand
from katana_common.messages import duration_msg
from katana_description import arm_contract as ac
from katana_description import gripper_contract as gc
from trajectory_msgs.msg import JointTrajectoryPoint

from katana_driver.core.encoders import ARM_JOINTS
from katana_driver.core.motion import TrajectoryFeedback

RESET_MESSAGE = (
    "hardware backend: the blocks cannot be reset by software; an operator must scatter them "
    "by hand in the play area, then continue"
)


def trajectory_feedback(fb: TrajectoryFeedback, stamp) -> FollowJointTrajectory.Feedback:
    msg = FollowJointTrajectory.Feedback(joint_names=list(ARM_JOINTS))
    msg.header.stamp = stamp
    at = duration_msg(max(0.0, fb.elapsed_s))
    msg.desired = JointTrajectoryPoint(positions=fb.desired, time_from_start=at)
    msg.actual = JointTrajectoryPoint(positions=fb.actual, time_from_start=at)
    msg.error = JointTrajectoryPoint(positions=fb.error, time_from_start=at)
    return msg


def trajectory_result(outcome: ac.Outcome) -> FollowJointTrajectory.Result:
    return FollowJointTrajectory.Result(error_code=outcome.error_code,
                                        error_string=outcome.message)


def gripper_goal(msg: GripperCommand.Goal) -> gc.GripperGoal:
    return gc.GripperGoal(position=msg.command.position, max_effort=msg.command.max_effort)


def gripper_result(outcome: gc.GripperOutcome) -> GripperCommand.Result:
    return GripperCommand.Result(position=float(outcome.position), effort=float(outcome.effort),
                                 stalled=outcome.stalled, reached_goal=outcome.reached_goal)


def gripper_feedback(outcome: gc.GripperOutcome) -> GripperCommand.Feedback:
    return GripperCommand.Feedback(position=float(outcome.position), effort=float(outcome.effort),
                                   stalled=outcome.stalled, reached_goal=outcome.reached_goal)
