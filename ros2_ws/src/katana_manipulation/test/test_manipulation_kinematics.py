"""Kinematics against PyBullet's own forward kinematics of the URDF, and against a numeric
search for the unreachable cases."""

from __future__ import annotations

import math

import numpy as np
import pybullet as p
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_description import models as m
from katana_description import urdf_path
from katana_manipulation.core.kinematics import KatanaKinematics, Unreachable, wrap
from scipy.optimize import least_squares


class UrdfFK:
    """PyBullet's forward kinematics of the committed URDF (independent of kinematics.py)."""

    def __init__(self, model: str = m.DEFAULT_MODEL) -> None:
        self.cid = p.connect(p.DIRECT)
        self.body = p.loadURDF(str(urdf_path(f"katana_{model}.urdf")), useFixedBase=True,
                               physicsClientId=self.cid)
        names = {}
        for i in range(p.getNumJoints(self.body, physicsClientId=self.cid)):
            info = p.getJointInfo(self.body, i, physicsClientId=self.cid)
            names[info[1].decode()] = i
            names[info[12].decode()] = i
        self.joints = [names[n] for n in m.ARM_JOINTS]
        self.tool = names["katana_gripper_tool_frame"]

    def __call__(self, q) -> np.ndarray:
        for j, v in zip(self.joints, q, strict=True):
            p.resetJointState(self.body, j, float(v), physicsClientId=self.cid)
        st_ = p.getLinkState(self.body, self.tool, computeForwardKinematics=True,
                             physicsClientId=self.cid)
        t = np.eye(4)
        t[:3, :3] = np.array(p.getMatrixFromQuaternion(st_[5])).reshape(3, 3)
        t[:3, 3] = st_[4]
        return t


@pytest.fixture(scope="module")
def urdf_fk():
    fk = UrdfFK()
    yield fk
    p.disconnect(fk.cid)


KIN = KatanaKinematics()


def test_fk_matches_urdf_over_random_joint_angles(urdf_fk):
    rng = np.random.default_rng(0)
    for _ in range(300):
        q = rng.uniform(KIN.lower, KIN.upper)
        assert np.allclose(KIN.fk(q), urdf_fk(q), atol=5e-5)  # PyBullet stores float32


def test_fk_matches_katana_md_checks():
    assert np.allclose(KIN.tool_position([0, 0, 0, 0, 0]), [0.6318, 0, 0.2015], atol=1e-4)
    assert np.allclose(KIN.tool_position([0, 1.5708, 0, 0, 0]), [0.0, 0, 0.8333], atol=1e-3)


@settings(max_examples=300, deadline=None)
@given(
    x=st.floats(0.05, 0.33), y=st.floats(-0.3, 0.3), z=st.floats(-0.01, 0.16),
    yaw=st.floats(-math.pi, math.pi),
)
def test_ik_solutions_reach_the_pose_in_the_urdf(urdf_fk, x, y, z, yaw):
    try:
        q = KIN.ik_top_down(x, y, z, yaw)
    except Unreachable as exc:
        assert "no top-down solution" in str(exc)
        return
    assert KIN.limit_violation(q) is None
    t = urdf_fk(q)
    assert np.allclose(t[:3, 3], [x, y, z], atol=1e-4)
    assert np.allclose(t[:3, 0], [0, 0, -1], atol=1e-4)  # approach axis straight down
    # fingers close along yaw + pi/2 (mod pi: the gripper is symmetric)
    closing = math.atan2(t[1, 1], t[0, 1])
    assert abs(wrap(2 * (closing - yaw - math.pi / 2))) < 2e-3


def _numeric_top_down(x, y, z, starts) -> float:
    """Smallest residual a bounded least-squares search finds for a top-down pose at (x, y, z),
    any yaw: an independent check that the closed form misses no solution."""
    lo, hi = KIN.lower[:4], KIN.upper[:4]

    def resid(q4):
        t = KIN.fk(list(q4) + [0.0])
        return np.concatenate([t[:3, 3] - [x, y, z], 0.1 * (t[:3, 0] - [0, 0, -1])])

    best = math.inf
    for q0 in starts:
        sol = least_squares(resid, np.clip(q0, lo + 1e-6, hi - 1e-6), bounds=(lo, hi))
        best = min(best, float(np.linalg.norm(sol.fun)))
    return best


def test_unreachable_targets_have_no_solution_by_numeric_search():
    rng = np.random.default_rng(3)
    starts = [rng.uniform(KIN.lower[:4], KIN.upper[:4]) for _ in range(12)]
    checked = 0
    while checked < 15:
        x, y, z = rng.uniform(0.0, 0.4), rng.uniform(-0.3, 0.3), rng.uniform(0.0, 0.2)
        try:
            KIN.ik_top_down(x, y, z, 0.0, yaw_period=math.pi / 2)
            continue
        except Unreachable:
            pass
        # only targets clearly away from the boundary: the residual must be well above zero
        assert _numeric_top_down(x, y, z, starts) > 1e-4, (x, y, z)
        checked += 1


def test_unreachable_reasons_are_clear():
    with pytest.raises(Unreachable, match="outside the arm's"):
        KIN.ik_top_down(0.5, 0.0, 0.0, 0.0)
    with pytest.raises(Unreachable, match="non-finite"):
        KIN.ik_top_down(math.nan, 0.0, 0.0, 0.0)
    with pytest.raises(Unreachable, match="katana_motor4_lift_joint"):
        KIN.ik_top_down(0.26, 0.13, 0.05, 0.0)


def test_yaw_choice_prefers_small_wrist_roll_and_respects_period():
    q = KIN.ik_top_down(0.2, 0.0, 0.02, 1.4, yaw_period=math.pi / 2)
    assert abs(q[4]) <= math.pi / 4 + 1e-9
    q2 = KIN.ik_top_down(0.2, 0.0, 0.02, 1.4, yaw_period=math.pi)
    assert abs(wrap(2 * (KIN.gripper_yaw(q2) - 1.4))) < 1e-9


def test_solutions_keep_the_drivers_limit_margin():
    """The inverse kinematics' limits are the joint limits less 200 encoders (docs/KATANA.md's
    ticks per revolution), a hair more for rounding; the park pose lies inside them."""
    kin = KatanaKinematics()
    per_rad = np.array([51200, 94976, 47488, 51200, 51200]) / (2 * math.pi)
    lower = np.array([m.JOINT_LIMITS[j][0] for j in m.ARM_JOINTS])
    upper = np.array([m.JOINT_LIMITS[j][1] for j in m.ARM_JOINTS])
    assert np.all((kin.lower - lower) * per_rad >= 200.0)
    assert np.all((upper - kin.upper) * per_rad >= 200.0)
    assert np.all((kin.lower - lower) * per_rad <= 200.5)
    assert np.all((upper - kin.upper) * per_rad <= 200.5)
    assert kin.limit_violation(m.PARK_POSE) is None
    rng = np.random.default_rng(0)
    for _ in range(200):
        r, a, z = rng.uniform(0.05, 0.35), rng.uniform(-math.pi, math.pi), rng.uniform(0.0, 0.2)
        try:
            q = kin.ik_top_down(r * math.cos(a), r * math.sin(a), z, rng.uniform(-3, 3))
        except Unreachable:
            continue
        assert np.all(np.minimum(q - lower, upper - q) * per_rad >= 200.0)
