"""Encoder conversion per model: KNI's cfg numbers, URDF limits, golden values, round trips."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_description import arm_contract as ac
from katana_description import models
from katana_driver.core.arm import CALIBRATION_BACKOFF_SLACK_ENC
from katana_driver.core.encoders import (
    ARM_JOINTS,
    KNI_CONFIGS,
    VARIANTS,
    EncoderModel,
)
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
    enc = EncoderModel.for_model(model_name)
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


# ---------------------------------------------------------------- every model, from KNI's cfg

# The cfg numbers, written out again as the reference (docs/KATANA.md, per-model table):
# encodersPerCycle and angleRange (degrees) of motors 1..5; every 6M180 cfg shares the
# encoder offsets, angle offsets and directions below.
KNI_TICKS = {
    "450_6m180": (51200, 94976, 47488, 51200, 51200),  # configfiles450/katana6M180.cfg
    "400_6m180": (51200, 94976, 47488, 51200, 51200),  # configfiles400/katana6M180.cfg
    "300_6m180": (51200, 94976, 81408, 51200, 51200),  # configfiles300/katana6M180.cfg
}
KNI_RANGES = {
    "450_6m180": (339.0, -132.0, 245.0, 224.0, 336.0),
    "400_6m180": (346.0, -140.0, 250.0, 230.0, 342.0),
    "300_6m180": (346.7, -143.0, 250.0, 232.7, 342.8),
}
KNI_ENC_OFFSETS = (31000, -31000, -31000, 31000, 31000)
KNI_ANGLE_OFFSETS = (6.65, 124.25, 52.7, 63.5, 8.5)
KNI_DIRECTIONS = (1, 1, -1, 1, 1)
URDF_SHIFT = (math.pi, 0.0, math.pi, math.pi, math.pi)  # the ROS 1 node's KNIConverter


def kni_enc2rad(model: str, motor: int, enc: float) -> float:
    """KNI's enc2rad (angleOffset - (enc - encoderOffset) 2 pi / (epc dir)), then the ROS 1
    node's shift and wrap to [-pi, pi): the reference, written from the formula."""
    i = motor - 1
    theta = math.radians(KNI_ANGLE_OFFSETS[i]) - (enc - KNI_ENC_OFFSETS[i]) * 2 * math.pi / (
        KNI_TICKS[model][i] * KNI_DIRECTIONS[i])
    return (theta - URDF_SHIFT[i] + math.pi) % (2 * math.pi) - math.pi


def kni_encoder_stop(model: str, motor: int) -> int:
    """CMotBase::setInitialParameters: encoderOffset - dir * int(epc * angleRange / 2 pi),
    angleRange in radians."""
    i = motor - 1
    rng = math.radians(KNI_RANGES[model][i])
    return KNI_ENC_OFFSETS[i] - KNI_DIRECTIONS[i] * int(KNI_TICKS[model][i] * (rng / (2 * math.pi)))


# Golden encoder ranges and joint limits (rad, URDF angles) of motors 1..5, per model.
GOLDEN = {
    "450_6m180": [((-17213, 31000), (-3.025528, 2.891097)), ((-31000, 3824), (-0.135228, 2.168572)),
                  ((-31000, 1318), (-2.221804, 2.054223)), ((-857, 31000), (-2.033309, 1.876133)),
                  ((-16786, 31000), (-2.993240, 2.870985))],
    "400_6m180": [((-18208, 31000), (-3.025528, 3.013202)), ((-31000, 5935), (-0.274882, 2.168572)),
                  ((-31000, 1977), (-2.221804, 2.141416)), ((-1711, 31000), (-2.033309, 1.980935)),
                  ((-17640, 31000), (-2.993240, 2.975786))],
    "300_6m180": [((-18308, 31000), (-3.025528, 3.025474)), ((-31000, 6726), (-0.327211, 2.168572)),
                  ((-31000, 25533), (-2.221804, 2.141493)), ((-2095, 31000), (-2.033309, 2.028059)),
                  ((-17753, 31000), (-2.993240, 2.989654))],
}
MODELS = sorted(KNI_TICKS)


def test_every_model_the_driver_accepts_has_an_encoder_model():
    assert set(KNI_CONFIGS) == set(models.MODELS) == set(MODELS)


@pytest.mark.parametrize("model", MODELS)
def test_the_model_name_picks_the_kni_numbers(model):
    enc = EncoderModel.for_model(model)
    assert enc.katana_type == int(model[:3]) and enc.variant == "6M180"
    assert enc.config is KNI_CONFIGS[model]
    for motor in range(1, 6):
        m = enc.params(motor)
        i = motor - 1
        assert (m.ticks_per_rev, m.encoder_offset, m.angle_offset_deg, m.direction,
                m.angle_range_deg) == (KNI_TICKS[model][i], KNI_ENC_OFFSETS[i],
                                       KNI_ANGLE_OFFSETS[i], KNI_DIRECTIONS[i],
                                       KNI_RANGES[model][i])


def test_the_300s_motor_3_has_81408_ticks_per_cycle():
    assert EncoderModel.for_model("300_6m180").params(3).ticks_per_rev == 81408
    assert EncoderModel.for_model("450_6m180").params(3).ticks_per_rev == 47488
    assert EncoderModel.for_model("400_6m180").params(3).ticks_per_rev == 47488


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("motor", [1, 2, 3, 4, 5])
def test_encoder_ranges_and_joint_limits_per_model(model, motor):
    enc = EncoderModel.for_model(model)
    (lo_enc, hi_enc), (lower, upper) = GOLDEN[model][motor - 1]
    stop = kni_encoder_stop(model, motor)
    assert enc.encoder_range(motor) == (lo_enc, hi_enc)
    assert {lo_enc, hi_enc} == {KNI_ENC_OFFSETS[motor - 1], stop}
    assert enc.joint_limits(motor) == pytest.approx((lower, upper), abs=1e-6)
    ends = sorted(kni_enc2rad(model, motor, e) for e in (lo_enc, hi_enc))
    assert enc.joint_limits(motor) == pytest.approx(ends, abs=1e-12)


@pytest.mark.parametrize(
    ("model", "motor", "encoder", "angle"),
    [
        ("300_6m180", 3, -25545, -1.800779),  # the 450 reads this encoder as -1.500048
        ("450_6m180", 3, -25545, -1.500048),
        ("400_6m180", 3, -25545, -1.500048),
        ("300_6m180", 3, 908, 0.240901),  # where the 450's 2.0 rad lands on a 300
        ("450_6m180", 3, 908, 1.999976),
        ("450_6m180", 1, 31000, -3.025528),
        ("300_6m180", 2, 6726, -0.327211),
        ("400_6m180", 5, 0, 0.811033),
        ("300_6m180", 4, 0, 1.770964),
    ],
)
def test_golden_encoders_to_angles_and_back(model, motor, encoder, angle):
    enc = EncoderModel.for_model(model)
    assert enc.encoder_to_angle(motor, encoder) == pytest.approx(angle, abs=1e-6)
    assert enc.encoder_to_angle(motor, encoder) == pytest.approx(
        kni_enc2rad(model, motor, encoder), abs=1e-12)
    assert enc.angle_to_encoder(motor, enc.encoder_to_angle(motor, encoder)) == pytest.approx(
        encoder, abs=1e-6)


def test_a_450_target_on_a_300_lands_elsewhere():
    """Why the 450's numbers must not drive a 300: 2.0 rad on motor 3 is encoder 908 with
    47488 ticks per cycle, which a 300 (81408) reads as about 0.24 rad."""
    target = EncoderModel.for_model("450_6m180").angle_to_encoder(3, 2.0)
    assert round(target) == 908
    assert EncoderModel.for_model("300_6m180").encoder_to_angle(3, target) == pytest.approx(
        0.2409, abs=1e-4)


@pytest.mark.parametrize(
    ("model", "open_enc", "closed_enc", "motor_range"),
    [
        ("450_6m180", 30770, 12240, (-15791, 31000)),  # motor 6: 31000 - int(51200 * 329/360)
        ("400_6m180", 30770, 12240, (-15791, 31000)),
        ("300_6m180", 31000, -16768, (-16768, 31000)),  # the 300 cfg's open/close encoders
    ],
)
def test_gripper_encoders_per_model(model, open_enc, closed_enc, motor_range):
    enc = EncoderModel.for_model(model)
    assert enc.gripper_encoder_to_angle(open_enc) == pytest.approx(models.GRIPPER_OPEN)
    assert enc.gripper_encoder_to_angle(closed_enc) == pytest.approx(models.GRIPPER_CLOSED)
    assert enc.gripper_angle_to_encoder(models.GRIPPER_OPEN) == pytest.approx(open_enc)
    assert enc.gripper_encoder_range() == motor_range
    lo, hi = motor_range
    assert lo <= closed_enc < open_enc <= hi


def test_the_450_gripper_map_is_the_ros1_nodes():
    """katana_constants.h: KNI_GRIPPER_CLOSED_ANGLE 0.21652991032554647, KNI_GRIPPER_OPEN_ANGLE
    -2.057443 rad are the 450 cfg's closeEncoders 12240 and openEncoders 30770 through motor
    6's numbers (51200 ticks, offset 31000, angle offset -119.5 degrees, direction +)."""
    def kni_gripper(e):
        return math.radians(-119.5) - (e - 31000) * 2 * math.pi / 51200

    assert kni_gripper(12240) == pytest.approx(0.21652991032554647, abs=1e-12)
    assert kni_gripper(30770) == pytest.approx(-2.057443, abs=1e-6)


@settings(deadline=None)  # no timed asserts: a loaded machine is not a bug
@given(st.sampled_from(MODELS), st.sampled_from(VARIANTS), st.integers(1, 5), st.data())
def test_encoder_angle_encoder_round_trip_per_model(model, variant, motor, data):
    enc = EncoderModel(variant, int(model[:3]))
    lo, hi = enc.encoder_range(motor)
    e = data.draw(st.integers(lo, hi))
    angle = enc.encoder_to_angle(motor, e)
    assert -math.pi <= angle < math.pi
    assert enc.angle_to_encoder(motor, angle) == pytest.approx(e, abs=1e-6)
    if variant != "6M90B":
        assert angle == pytest.approx(kni_enc2rad(model, motor, e), abs=1e-12)


@settings(deadline=None)  # no timed asserts: a loaded machine is not a bug
@given(st.sampled_from(MODELS), st.data())
def test_gripper_encoder_angle_encoder_round_trip_per_model(model, data):
    enc = EncoderModel.for_model(model)
    lo, hi = enc.gripper_encoder_range()
    e = data.draw(st.integers(lo, hi))
    assert enc.gripper_angle_to_encoder(enc.gripper_encoder_to_angle(e)) == pytest.approx(
        e, abs=1e-6)


@pytest.mark.parametrize("model", MODELS)
def test_katana_description_limits_agree_with_the_cfg(model):
    """The 450's URDF limits are its cfg's ranges (to the URDF's 6 decimals). The 300's and
    400's URDF limits (the ROS 1 files', copies of the 450's) lie inside their wider cfg
    ranges: the arm contract, which applies them, is the stricter of the two."""
    enc = EncoderModel.for_model(model)
    limits = models.get_model(model).limits
    for motor, joint in enumerate(models.ARM_JOINTS, start=1):
        lower, upper = enc.joint_limits(motor)
        if model == "450_6m180":
            assert limits[joint] == pytest.approx((lower, upper), abs=1e-6)
        else:
            assert lower - 1e-6 <= limits[joint][0] < limits[joint][1] <= upper + 1e-6


def test_unknown_katana_type_is_refused():
    with pytest.raises(ValueError, match="Katana type 350"):
        EncoderModel("6M180", 350)
