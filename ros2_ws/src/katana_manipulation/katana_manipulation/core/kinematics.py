"""Forward and inverse kinematics of the Katana 6M180 (gripper in line with the wrist). ROS-free.

Joint angles follow the ROS 1 URDF conventions (katana_description/models.py): q1 pans about
+z, q2..q4 lift (the elevation of link 3 is q2 + q3, of link 4 and the gripper q2 + q3 - q4),
q5 rolls the wrist. The inverse kinematics is closed form for a top-down grasp: the approach
axis is -z, so the motor-4 joint sits straight above the tool point and the shoulder-elbow-wrist
triangle is solved with the law of cosines; q5 then sets the gripper's yaw. Every solution is
checked against the target limits (the joint limits less the driver's limit margin, the arm
contract's `target_limits`), and an unreachable target raises `Unreachable` with the reason.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from katana_description import models as m

ARM_JOINTS = m.ARM_JOINTS
#: the planner's targets keep this much (rad, under 0.2 encoders) inside the target limits, so
#: that the driver's encoder check, on the exact encoder model, never finds one on the line
TARGET_SLACK_RAD = 1e-5
#: where every planned pose lies: the joint limits shrunk by models.LIMIT_MARGIN_ENC encoders
#: (what the arm contract and the driver accept as targets; a real controller refuses targets
#: closer to its limits)
TARGET_LIMITS = m.inner_limits(m.JOINT_LIMITS, m.LIMIT_MARGIN_ENC)
LOWER = np.array([TARGET_LIMITS[j][0] for j in ARM_JOINTS]) + TARGET_SLACK_RAD
UPPER = np.array([TARGET_LIMITS[j][1] for j in ARM_JOINTS]) - TARGET_SLACK_RAD
MAX_SPEED = np.array([m.JOINT_MAX_SPEED[j] for j in ARM_JOINTS])
#: rad/s^2: the controller's acceleration limit (models.KNI_MAX_ACCELERATION) per joint
MAX_ACCEL = np.array([m.JOINT_MAX_ACCEL[j] for j in ARM_JOINTS])


class Unreachable(ValueError):
    """No joint solution for the requested pose; str() says why."""


def _rot(axis: str, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    t = np.eye(4)
    if axis == "x":
        t[1:3, 1:3] = [[c, -s], [s, c]]
    elif axis == "y":
        t[0, 0], t[0, 2], t[2, 0], t[2, 2] = c, s, -s, c
    else:
        t[0:2, 0:2] = [[c, -s], [s, c]]
    return t


def _trans(x: float, y: float, z: float) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = (x, y, z)
    return t


def _rpy(r: float, p: float, y: float) -> np.ndarray:
    return _rot("z", y) @ _rot("y", p) @ _rot("x", r)


def wrap(angle: float) -> float:
    """Angle wrapped to [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


class KatanaKinematics:
    """Kinematics of one Katana type (see katana_description.models.MODELS)."""

    def __init__(self, model: str = m.DEFAULT_MODEL) -> None:
        self.model = m.get_model(model)
        self.lower = LOWER.copy()
        self.upper = UPPER.copy()
        # Heading of the gripper's closing axis (+y of the tool frame) when q5 = 0, relative to
        # the pan angle, for a top-down pose. Constant, because every lift axis is horizontal.
        q = self._top_down_planar(0.25, 0.05)
        frame = self.fk(np.array([0.0, q[0], q[1], q[2], 0.0]))
        self._yaw_offset = math.atan2(frame[1, 1], frame[0, 1]) - math.pi / 2.0

    # ---------------------------------------------------------------- forward kinematics
    def chain(self, q: Sequence[float]) -> list[np.ndarray]:
        """World transforms of: motor 1..5 joint frames, the gripper link and the tool frame."""
        q1, q2, q3, q4, q5 = (float(v) for v in q[:5])
        md = self.model
        t1 = _trans(0, 0, m.BASE_HEIGHT) @ _rot("z", q1)
        t2 = t1 @ _rpy(math.pi / 2, 0, 0) @ _rot("z", q2)
        t3 = t2 @ _trans(m.LINK2, 0, 0) @ _rot("z", q3)
        t4 = t3 @ _trans(m.LINK3, 0, 0) @ _rpy(math.pi, 0, 0) @ _rot("z", q4)
        t5 = t4 @ _trans(md.link4, 0, 0) @ _rpy(math.pi / 2, 0, -math.pi / 2) @ _rot("z", q5)
        grip = t5 @ _trans(0, 0, -m.WRIST_TO_GRIPPER) @ _rpy(0, math.pi / 2, 0)
        tool = grip @ _trans(md.tool - m.WRIST_TO_GRIPPER, 0, 0)
        return [t1, t2, t3, t4, t5, grip, tool]

    def fk(self, q: Sequence[float]) -> np.ndarray:
        """4x4 world transform of the tool frame (x: approach axis, y: towards the r finger)."""
        return self.chain(q)[-1]

    def tool_position(self, q: Sequence[float]) -> np.ndarray:
        return self.fk(q)[:3, 3].copy()

    # ---------------------------------------------------------------- inverse kinematics
    def _top_down_planar(self, r: float, z: float, elbow_up: bool = True) -> tuple[float, ...]:
        """q2, q3, q4 putting the tool at horizontal distance r (in the arm's plane), height z,
        pointing straight down. Raises Unreachable when the triangle cannot close."""
        md = self.model
        zw = z + md.link4 + md.tool - m.BASE_HEIGHT  # motor-4 joint above the shoulder
        d2 = r * r + zw * zw
        c3 = (d2 - m.LINK2**2 - m.LINK3**2) / (2.0 * m.LINK2 * m.LINK3)
        if c3 > 1.0 or c3 < -1.0:
            d = math.sqrt(d2)
            raise Unreachable(
                f"wrist point {d:.3f} m from the shoulder, outside the arm's "
                f"{abs(m.LINK2 - m.LINK3):.3f}..{m.LINK2 + m.LINK3:.3f} m"
            )
        q3 = math.acos(c3) * (-1.0 if elbow_up else 1.0)
        q2 = math.atan2(zw, r) - math.atan2(m.LINK3 * math.sin(q3),
                                            m.LINK2 + m.LINK3 * math.cos(q3))
        q4 = q2 + q3 + math.pi / 2.0  # gripper elevation q2 + q3 - q4 = -pi/2
        return q2, q3, q4

    def limit_violation(self, q: Sequence[float], tol: float = 1e-9) -> str | None:
        """Why q breaks a joint limit, or None."""
        for name, v, lo, hi in zip(ARM_JOINTS, q, self.lower, self.upper, strict=False):
            if not (lo - tol <= v <= hi + tol):
                return f"{name} would be {v:.3f} rad, outside [{lo:.3f}, {hi:.3f}]"
        return None

    def ik_top_down(self, x: float, y: float, z: float, yaw: float,
                    yaw_period: float = math.pi, q5_preferred: float = 0.0) -> np.ndarray:
        """Joint angles putting the tool point at (x, y, z), pointing straight down, with the
        fingers closing along the direction `yaw + pi/2` (the gripper's yaw is `yaw`).

        Yaws that differ by a multiple of `yaw_period` are equivalent (pi for the symmetric
        gripper, pi/2 for a square block); the one whose q5 is closest to `q5_preferred` and
        within limits wins. Raises Unreachable with the reason when no solution exists.
        """
        values = (x, y, z, yaw)
        if not all(math.isfinite(v) for v in values):
            raise Unreachable(f"target has a non-finite value: {values}")
        if yaw_period <= 0:
            raise ValueError("yaw_period must be positive")
        r = math.hypot(x, y)
        candidates = []
        pan = math.atan2(y, x) if r > 1e-9 else 0.0
        # Reach forward (pan towards the target) or, where the pan range ends, over the top.
        for q1, rr in ((pan, r), (wrap(pan + math.pi), -r)):
            candidates.append((q1, rr))
        reasons: list[str] = []
        best: np.ndarray | None = None
        best_cost = math.inf
        for q1, rr in candidates:
            for elbow_up in (True, False):
                try:
                    q2, q3, q4 = self._top_down_planar(rr, z, elbow_up)
                except Unreachable as exc:
                    reasons.append(str(exc))
                    continue
                arm = np.array([q1, q2, q3, q4, 0.0])
                why = self.limit_violation(arm[:4])
                if why is not None:
                    reasons.append(why)
                    continue
                base = wrap(yaw - q1 - self._yaw_offset)
                n = int(math.ceil(2.0 * math.pi / yaw_period)) + 1
                lo, hi = self.lower[4], self.upper[4]
                q5s = [base + k * yaw_period for k in range(-n, n + 1)]
                q5s = [v for v in q5s if lo <= v <= hi]
                if not q5s:
                    reasons.append(f"the wrist roll cannot turn the gripper to yaw {yaw:.3f}")
                    continue
                for q5 in q5s:
                    cost = abs(q5 - q5_preferred) + (0.0 if elbow_up else 10.0)
                    if cost < best_cost:
                        best, best_cost = np.array([q1, q2, q3, q4, q5]), cost
        if best is None:
            # The first reason belongs to the natural (forward, elbow-up) configuration.
            raise Unreachable(f"no top-down solution at ({x:.3f}, {y:.3f}, {z:.3f}): {reasons[0]}")
        return best

    def gripper_yaw(self, q: Sequence[float]) -> float:
        """Yaw of a top-down gripper: the inverse of what ik_top_down takes (mod pi)."""
        frame = self.fk(q)
        return wrap(math.atan2(frame[1, 1], frame[0, 1]) - math.pi / 2.0)

    def reachable(self, x: float, y: float, z: float, yaw: float = 0.0,
                  yaw_period: float = math.pi) -> bool:
        try:
            self.ik_top_down(x, y, z, yaw, yaw_period)
        except Unreachable:
            return False
        return True
