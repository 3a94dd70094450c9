"""The emulated controller against the vendor's facts: KNI's version check, the encoder ranges
behind the URDF's joint limits, refusals within the margin of the stops, the 300's firmware,
and the block option's stall against the documented jaw openings."""

from __future__ import annotations

import math
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_description import models
from katana_emulator import wire
from katana_emulator.arms import MODELS
from katana_emulator.model import HOLDING, MOVING, KatanaModel

REFUSED = bytes((wire.ERROR_BYTE,))


class Clock:
    """A manual clock: the model moves only when the test says so."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def model_at(clock: Clock | None = None, **kw) -> KatanaModel:
    return KatanaModel(calibrated=True, clock=clock or Clock(), **kw)


def move(motor: int, target: int) -> bytes:
    return struct.pack(">BBBh", ord("C"), motor, 24, target)


def explanation(model: KatanaModel) -> str:
    return model.error_reply()[4:55].split(b"\x00", 1)[0].decode()


def kni_accepts(katana_type: int, version: int) -> bool:
    """KNI 4.3.0's CKatBase::checkKatanaType: a 400/450 needs version <= 3, a 300 >= 3."""
    if katana_type in (400, 450):
        return version <= 3
    return version >= 3


@pytest.mark.parametrize("katana_type", [300, 400, 450])
def test_the_master_version_is_one_kni_accepts_for_the_type(katana_type):
    reply = model_at(katana_type=katana_type).handle(b"B")
    assert reply[0] == ord("b") and kni_accepts(katana_type, reply[1])


def test_the_450s_encoder_ranges_span_the_urdf_joint_limits():
    """Each range, converted with KNI's ticks per cycle, is the URDF joint's span (the URDF
    limits were computed by KNI from the same configuration), and motor 6's range is KNI's
    -15791..31000 (docs/KATANA.md)."""
    arm = MODELS[450]
    for axis, joint in zip(arm.axes, models.ARM_JOINTS, strict=True):
        lo, hi = axis.encoder_range
        span = (hi - lo) * 2.0 * math.pi / axis.ticks_per_cycle
        lower, upper = models.JOINT_LIMITS[joint]
        assert span == pytest.approx(upper - lower, abs=2e-4), joint
        assert axis.ticks_per_cycle == models.ENCODERS_PER_REV[joint]
    assert arm.gripper.encoder_range == (-15791, 31000)


@pytest.mark.parametrize("katana_type", [300, 400, 450])
@settings(deadline=None)  # no timed asserts: the machine may be loaded
@given(motor=st.integers(1, 6), offset=st.integers(-400, 400), at_top=st.booleans())
def test_move_targets_within_200_of_a_stop_are_refused_with_the_error_reply(
        katana_type, motor, offset, at_top):
    """The controller's margin: a move to 200 encoders or less from either end of a motor's
    range is refused (0xC0, explained on 0xC1), never clamped; farther in is taken."""
    model = model_at(katana_type=katana_type)
    lo, hi = model.motors[motor - 1].lo, model.motors[motor - 1].hi
    target = hi - 200 + offset if at_top else lo + 200 - offset
    inside = offset <= 0
    reply = model.handle(move(motor, target))
    if inside:
        assert reply == bytes((ord("c"), 1, motor))
        assert model.motors[motor - 1].target == target
    else:
        assert reply == REFUSED
        assert explanation(model).startswith("Target too close to the limit")
        assert model.motors[motor - 1].status == HOLDING  # nothing moved


def test_a_spline_ending_near_a_stop_is_refused():
    model = model_at()
    lo = model.motors[0].lo
    here = model.encoders()
    rows = [wire.Segment(50, e, e, 0, 0, 0) for e in here]
    rows[0] = wire.Segment(100, lo + 150, here[0], 0, 0, 0)  # p0 far from the target: moves
    payload = b"H" + struct.pack(">36h", *(v for s in rows for v in s.fields())) + b"\x01\x00"
    assert model.handle(payload) == REFUSED
    assert explanation(model).startswith("Target too close to the limit")


def test_the_300_takes_no_h_no_flush_and_calibrates_motor_by_motor():
    model = KatanaModel(katana_type=300, calibration_s=0.1, clock=Clock())
    hold = b"H" + bytes(72) + b"\x01\x00"
    assert model.handle(hold) == REFUSED
    assert "takes no H" in explanation(model)
    assert model.handle(struct.pack(">BBBh", ord("C"), 0, 4, 32000)) == REFUSED
    assert "motor by motor" in explanation(model)
    for motor in range(1, 7):
        assert model.handle(struct.pack(">BBBh", ord("C"), motor, 4, 0))[1] == 1
    assert model.handle(struct.pack(">BBBh", ord("C"), 0, 32, 0)) == REFUSED
    assert "no flush" in explanation(model)
    model.finish_calibration_now()
    g = struct.pack(">BBhhhhhh", ord("G"), 1, 20000, 50, 20000, 0, 0, 0)
    assert model.handle(g) == bytes((ord("g"), 1))


def test_the_450_takes_h_flush_and_calibrate_all():
    model = KatanaModel(calibration_s=0.1, clock=Clock())
    assert model.handle(struct.pack(">BBBh", ord("C"), 0, 4, 32000))[1] == 1
    model.finish_calibration_now()
    here = model.encoders()
    rows = [wire.Segment(20, e, e, 0, 0, 0) for e in here]
    payload = b"H" + struct.pack(">36h", *(v for s in rows for v in s.fields())) + b"\x01\x00"
    assert model.handle(payload) == bytes((ord("h"), 1, 1))
    assert model.handle(struct.pack(">BBBh", ord("C"), 0, 32, 0))[1] == 1


def close_gripper(model: KatanaModel, clock: Clock, target: int) -> int:
    assert model.handle(move(6, target))[1] == 1
    for _ in range(100):
        clock.t += 0.5
        model.advance()
    return model.encoders()[5]


def gripper_encoder(angle: float) -> float:
    """docs/KATANA.md: open at 30770 (0.30 rad), closed at 12240 (-0.44 rad), linear."""
    return 12240 + (angle + 0.44) / 0.74 * (30770 - 12240)


def test_without_a_block_the_fingers_close_until_they_touch():
    clock = Clock()
    model = model_at(clock)
    assert close_gripper(model, clock, 5000) == 12240
    assert model.motors[5].status == MOVING  # still pushing: the target lies beyond touching


def test_a_63_mm_block_holds_the_fingers_at_zero_rad():
    """docs/KATANA.md: the jaws stand about 6.3 cm apart at 0 rad."""
    clock = Clock()
    model = model_at(clock, block_width_m=0.063)
    assert close_gripper(model, clock, 12240) == pytest.approx(gripper_encoder(0.0), abs=2)


@pytest.mark.parametrize("width", [0.03, 0.04, 0.05])
def test_a_block_holds_the_fingers_where_the_planner_expects_it(width):
    """The stall lands within 0.01 rad of katana_description's finger angle for that opening
    (its lever is fitted to 6.3 cm at 0 and 9.7 cm at 0.30 rad; the pick-and-place check
    allows 0.08 rad), so a dry-run grasp reads as holding the block."""
    clock = Clock()
    model = model_at(clock, block_width_m=width)
    stalled = close_gripper(model, clock, 12240)
    want = gripper_encoder(models.finger_angle_for_opening(width))
    assert abs(stalled - want) <= 0.01 / 0.74 * (30770 - 12240)
    assert close_gripper(model, clock, 30770) == 30770  # opening is not held back


def test_a_block_wider_than_the_open_jaws_is_refused():
    with pytest.raises(ValueError, match="block width"):
        KatanaModel(block_width_m=0.2)
