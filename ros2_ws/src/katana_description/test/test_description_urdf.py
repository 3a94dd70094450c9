"""The generated URDFs: up to date with models.py, loadable, and faithful to docs/KATANA.md."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import pybullet as p
import pytest
from katana_description import models as m
from katana_description import urdf_gen

URDF_DIR = Path(__file__).resolve().parents[1] / "urdf"


def test_committed_urdfs_match_the_generator(tmp_path):
    for path in urdf_gen.write_all(tmp_path):
        assert (URDF_DIR / path.name).read_text() == path.read_text(), (
            f"{path.name} is stale: run python -m katana_description.urdf_gen")


@pytest.mark.parametrize("model", sorted(m.MODELS))
def test_arm_urdf_structure_limits_masses(model):
    root = ET.parse(URDF_DIR / f"katana_{model}.urdf").getroot()
    joints = {j.get("name"): j for j in root.iter("joint")}
    links = {link.get("name") for link in root.iter("link")}
    for name in m.ALL_JOINTS:
        lim = joints[name].find("limit")
        assert (float(lim.get("lower")), float(lim.get("upper"))) == m.JOINT_LIMITS[name]
        assert float(lim.get("velocity")) == m.JOINT_MAX_SPEED[name]
    for j in joints.values():  # a tree: every parent and child is a link
        assert j.find("parent").get("link") in links and j.find("child").get("link") in links
    mass = sum(float(e.get("value")) for e in root.iter("mass"))
    arm = sum(v for k, v in m.MASSES.items() if k != "finger") + 2 * m.MASSES["finger"]
    assert mass == pytest.approx(arm, abs=1e-3)
    for link in root.iter("link"):  # RViz and PyBullet need positive-definite inertias
        inertia = link.find("inertial/inertia")
        if inertia is not None:
            assert all(float(inertia.get(k)) > 0 for k in ("ixx", "iyy", "izz"))


def test_urdfs_load_in_pybullet_with_the_katana_md_geometry():
    cid = p.connect(p.DIRECT)
    try:
        body = p.loadURDF(str(URDF_DIR / "katana_450_6m180.urdf"), useFixedBase=True,
                          physicsClientId=cid)
        idx = {p.getJointInfo(body, i, physicsClientId=cid)[12].decode(): i
               for i in range(p.getNumJoints(body, physicsClientId=cid))}
        tool = idx["katana_gripper_tool_frame"]
        pos = p.getLinkState(body, tool, computeForwardKinematics=True, physicsClientId=cid)[4]
        assert pos == pytest.approx((0.632, 0.0, 0.2015), abs=1e-3)
        for name in ["table.urdf"] + [f"block_{c}.urdf" for c in m.COLOURS]:
            p.loadURDF(str(URDF_DIR / name), physicsClientId=cid)
    finally:
        p.disconnect(cid)


def test_gripper_openings_match_katana_md():
    assert m.finger_opening(-0.44) == pytest.approx(0.0, abs=1e-9)
    assert m.finger_opening(0.0) == pytest.approx(0.063, abs=0.002)
    assert m.finger_opening(0.30) == pytest.approx(0.097, abs=0.003)
    for w in (0.01, 0.04, 0.07):
        assert m.finger_opening(m.finger_angle_for_opening(w)) == pytest.approx(w)
    assert m.finger_angle_for_opening(0.04) == pytest.approx(m.FINGER_PAD_PARALLEL_AT, abs=2e-3)


def test_block_size_fills_the_fovea():
    # a block top 0.03 m above the table seen from 0.75 m with f = 750 px: about 40 px
    side_px = 750.0 * m.BLOCK_SIZE[0] / (0.75 - m.BLOCK_SIZE[2])
    assert 38 <= side_px <= 44
    assert math.isclose(m.BLOCK_MASS, 0.04)


def test_unmodelled_variants_fail_clearly():
    with pytest.raises(ValueError, match="not modelled"):
        m.get_model("450_6M90A")
    with pytest.raises(ValueError, match="unknown"):
        m.get_model("katana9000")
