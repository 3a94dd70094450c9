"""Encoder conversion: the URDF's limits, KATANA.md's examples, round trips."""

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st
from katana_driver.core.encoders import VARIANTS, EncoderModel

# Joint limits of the URDF (shared/KATANA.md table), motors 1..5.
URDF_LIMITS = [
    (-3.025528, 2.891097),
    (-0.135228, 2.168572),
    (-2.221804, 2.054223),
    (-2.033309, 1.876133),
    (-2.993240, 2.870985),
]


@pytest.mark.parametrize("variant", ["6M180", "6M90A"])
@pytest.mark.parametrize("motor", [1, 2, 3, 4, 5])
def test_encoder_range_reproduces_urdf_limits(variant, motor):
    lo, hi = EncoderModel(variant).joint_limits(motor)
    assert lo == pytest.approx(URDF_LIMITS[motor - 1][0], abs=2e-5)
    assert hi == pytest.approx(URDF_LIMITS[motor - 1][1], abs=2e-5)


def test_katana_md_examples():
    m = EncoderModel()
    assert m.encoder_to_angle(1, 31000) == pytest.approx(-3.025528, abs=1e-6)
    assert m.gripper_encoder_to_angle(30770) == pytest.approx(0.30)
    assert m.gripper_encoder_to_angle(12240) == pytest.approx(-0.44)
    assert m.speed_limit_enc(1) == pytest.approx(180.0, rel=1e-3)
    assert m.speed_limit_enc(3) == pytest.approx(90.0, rel=1e-3)


def test_motor3_turns_the_other_way():
    m = EncoderModel()
    assert m.encoder_to_angle(3, 0) > m.encoder_to_angle(3, -1000)
    assert m.encoder_to_angle(2, 0) < m.encoder_to_angle(2, -1000)


def test_6m90b_wrist_is_turned_half_a_turn():
    a, b = EncoderModel("6M90A"), EncoderModel("6M90B")
    for enc in (-16000, 0, 12345, 31000):
        diff = (b.encoder_to_angle(5, enc) - a.encoder_to_angle(5, enc)) % (2 * math.pi)
        assert diff == pytest.approx(math.pi, abs=1e-9)


@given(st.sampled_from(VARIANTS), st.integers(1, 5), st.data())
def test_encoder_angle_round_trip(variant, motor, data):
    m = EncoderModel(variant)
    lo, hi = m.encoder_range(motor)
    enc = data.draw(st.integers(lo, hi))
    angle = m.encoder_to_angle(motor, enc)
    assert -math.pi <= angle < math.pi
    assert m.angle_to_encoder(motor, angle) == pytest.approx(enc, abs=1e-6)


@given(st.floats(-0.44, 0.30))
def test_gripper_round_trip(angle):
    m = EncoderModel()
    assert m.gripper_encoder_to_angle(m.gripper_angle_to_encoder(angle)) == pytest.approx(angle)


def test_seven_joint_positions_with_equal_fingers():
    positions = EncoderModel().encoders_to_joint_positions([0, 0, 0, 0, 0, 20000])
    assert len(positions) == 7 and positions[5] == positions[6]


def test_unknown_variant_is_refused():
    with pytest.raises(ValueError, match="6M180"):
        EncoderModel("6M45")
