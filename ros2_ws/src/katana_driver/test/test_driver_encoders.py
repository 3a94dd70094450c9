"""Encoder conversion: the URDF's limits, docs/KATANA.md's examples, round trips."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_description import arm_contract as ac
from katana_description import models
from katana_driver.core.arm import CALIBRATION_BACKOFF_SLACK_ENC
from katana_driver.core.encoders import ARM_JOINTS, VARIANTS, EncoderModel, variant_of
from katana_driver.core.splines import plan_trajectory

# Joint limits of the URDF (docs/KATANA.md table), motors 1..5.
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


@settings(deadline=None)  # no timed asserts: a loaded machine is not a bug
@given(st.sampled_from(VARIANTS), st.integers(1, 5), st.data())
def test_encoder_angle_round_trip(variant, motor, data):
    m = EncoderModel(variant)
    lo, hi = m.encoder_range(motor)
    enc = data.draw(st.integers(lo, hi))
    angle = m.encoder_to_angle(motor, enc)
    assert -math.pi <= angle < math.pi
    assert m.angle_to_encoder(motor, angle) == pytest.approx(enc, abs=1e-6)


@settings(deadline=None)  # no timed asserts: a loaded machine is not a bug
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


@pytest.mark.parametrize("model_name", sorted(models.MODELS))
def test_the_calibrated_pose_is_a_valid_start_for_every_modelled_arm(model_name):
    """The cause of "pan would be -3.026 rad, outside [-3.026, 2.891]" after calibration: the
    stop converts to -3.0255282636 rad, 2.6e-7 below katana_description's rounded limit
    -3.025528. The back-off after calibration puts every motor at least 200 encoders (the
    margin a real controller is reported to keep) inside its stop, the +-31000 of KNI's
    configuration (encoderOffset), so the pose is inside every limit of the model and the arm
    contract and the planner accept a goal from it (to the park pose)."""
    _, variant = variant_of(model_name)
    enc = EncoderModel(variant)
    stops = enc.calibration_pose(0.0)
    limits = models.get_model(model_name).limits
    assert stops[0] < limits[models.ARM_JOINTS[0]][0]  # the stop itself: a hair outside
    backed_off = enc.backed_off_stops(200 + CALIBRATION_BACKOFF_SLACK_ENC)
    kni_stops = [31000, -31000, -31000, 31000, 31000]  # KNI cfg encoderOffset, motors 1..5
    for motor, (e, stop) in enumerate(zip(backed_off, kni_stops, strict=True), start=1):
        lo, hi = enc.encoder_range(motor)
        assert stop in (lo, hi)
        assert 200 <= abs(e - stop) <= 200 + 20 and lo + 200 <= e <= hi - 200
    pose = [enc.encoder_to_angle(m, e) for m, e in enumerate(backed_off, start=1)]
    for name, q in zip(models.ARM_JOINTS, pose, strict=True):
        lo, hi = limits[name]
        assert lo + 0.009 < q < hi - 0.009, name
    current = dict(zip(models.ARM_JOINTS, pose, strict=True))
    goal = ac.TrajectoryGoal(list(models.ARM_JOINTS), [4.0], [list(models.PARK_POSE)])
    assert ac.validate_trajectory(goal, current, ac.ArmContract(model=model_name)) == ac.OK
    plan = plan_trajectory(enc, [*backed_off, 20000], [4.0], [list(models.PARK_POSE)])
    assert plan.final_angles() == pytest.approx(list(models.PARK_POSE), abs=1e-4)


def test_driver_speeds_and_names_are_katana_descriptions():
    assert ARM_JOINTS == models.ARM_JOINTS
    for motor, name in enumerate(models.ARM_JOINTS, start=1):
        per_tick = EncoderModel().speed_limit_enc(motor)
        rad_s = per_tick / abs(EncoderModel().speed_to_encoder(motor, 1.0))
        assert rad_s == pytest.approx(models.JOINT_MAX_SPEED[name], rel=1e-12)
