"""Stamps and durations to and from seconds (float), one way for every node, and the
FollowJointTrajectory goal of both arm backends: the message <-> value conversions
katana_common shares (each package has its own messages.py)."""

from __future__ import annotations

import math

from builtin_interfaces.msg import Duration, Time
from katana_description import arm_contract as ac

_NS = 1_000_000_000


def _split(seconds: float) -> tuple[int, int]:
    if not math.isfinite(seconds):
        raise ValueError(f"{seconds!r} s is not finite")
    total_ns = int(round(seconds * _NS))
    sec, nanosec = divmod(total_ns, _NS)
    return sec, nanosec


def time_msg(seconds: float) -> Time:
    """builtin_interfaces/Time of `seconds` since the clock's epoch (>= 0)."""
    if seconds < 0:
        raise ValueError(f"a stamp cannot be negative: {seconds!r} s")
    sec, nanosec = _split(seconds)
    return Time(sec=sec, nanosec=nanosec)


def duration_msg(seconds: float) -> Duration:
    """builtin_interfaces/Duration of `seconds` (negative allowed, nanosec in [0, 1e9))."""
    sec, nanosec = _split(seconds)
    return Duration(sec=sec, nanosec=nanosec)


def to_seconds(msg: Time | Duration) -> float:
    """Seconds of a builtin_interfaces Time or Duration."""
    return float(msg.sec) + float(msg.nanosec) * 1e-9


def to_nanoseconds(msg: Time | Duration) -> int:
    """Nanoseconds of a builtin_interfaces Time or Duration, exactly (stamps compared as
    orderings)."""
    return int(msg.sec) * _NS + int(msg.nanosec)


def multi_dof_joints(goal) -> list[str]:
    """Joints a control_msgs/FollowJointTrajectory goal names in its multi-DOF parts
    (multi_dof_trajectory, component tolerances), "<unnamed>" for multi-DOF points without
    names: the Katana has no multi-DOF joint, so the arm contract refuses a goal with any."""
    traj = goal.multi_dof_trajectory
    names = list(traj.joint_names) or (["<unnamed>"] if traj.points else [])
    tolerances = (*goal.component_path_tolerance, *goal.component_goal_tolerance)
    return names + [t.joint_name for t in tolerances]


def trajectory_goal(msg) -> ac.TrajectoryGoal | ac.Verdict:
    """The arm contract's goal of a control_msgs/FollowJointTrajectory goal, or a refusal for
    what the contract does not see: more points than it takes (counted before any point is
    read) and non-finite velocity or acceleration parts of the tolerances. sim_node and
    katana_driver_node both take their goals through it."""
    count = ac.check_point_count(len(msg.trajectory.points))
    if not count.ok:
        return count
    for kind, tolerances in (("path", msg.path_tolerance), ("goal", msg.goal_tolerance)):
        for tol in tolerances:
            if not (math.isfinite(tol.velocity) and math.isfinite(tol.acceleration)):
                return ac.Verdict(ac.INVALID_GOAL, f"{kind} tolerance of {tol.name!r} is not "
                                  "finite")
    points = msg.trajectory.points
    return ac.TrajectoryGoal(
        joint_names=list(msg.trajectory.joint_names),
        times_s=[to_seconds(pt.time_from_start) for pt in points],
        positions=[list(pt.positions) for pt in points],
        velocities=[list(pt.velocities) for pt in points],
        path_tolerance=[(t.name, t.position) for t in msg.path_tolerance],
        goal_tolerance=[(t.name, t.position) for t in msg.goal_tolerance],
        goal_time_tolerance_s=to_seconds(msg.goal_time_tolerance),
        multi_dof_joints=multi_dof_joints(msg),
    )
