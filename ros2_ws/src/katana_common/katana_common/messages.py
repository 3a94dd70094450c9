"""Stamps and durations to and from seconds (float), one way for every node: the message <->
value conversions katana_common shares (each package has its own messages.py)."""

from __future__ import annotations

import math

from builtin_interfaces.msg import Duration, Time

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


def multi_dof_joints(goal) -> list[str]:
    """Joints a control_msgs/FollowJointTrajectory goal names in its multi-DOF parts
    (multi_dof_trajectory, component tolerances), "<unnamed>" for multi-DOF points without
    names: the Katana has no multi-DOF joint, so the arm contract refuses a goal with any."""
    traj = goal.multi_dof_trajectory
    names = list(traj.joint_names) or (["<unnamed>"] if traj.points else [])
    tolerances = (*goal.component_path_tolerance, *goal.component_goal_tolerance)
    return names + [t.joint_name for t in tolerances]
