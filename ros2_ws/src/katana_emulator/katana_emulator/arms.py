"""What the emulated controller knows of each Katana model: encoder ranges, firmware version,
the commands its firmware takes, and the gripper's geometry for the block option.

Numbers from KNI 4.3.0's configuration files and headers as docs/KATANA.md records them (the
emulator's own copy: nothing here is imported from the driver). A motor's encoder range is
KNI's: from ``encoderOffset`` to ``encoderOffset - dir * int(encodersPerCycle * angleRange /
360)``; calibration leaves it at ``encoderOffset``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: KNI's check of the master firmware version against the configured type
#: (CKatBase::checkKatanaType with kmlBase.h's K400_OLD_PROTOCOL_THRESHOLD = 3): a 400 or 450
#: is refused above 3, a 300 below 3.
KNI_PROTOCOL_THRESHOLD = 3


@dataclass(frozen=True)
class Axis:
    """One arm motor as KNI configures it."""

    ticks_per_cycle: int
    encoder_offset: int
    direction: int  # rotationDirection, +1 or -1
    angle_range_deg: float
    max_speed_rad_s: float  # the joint's nominal top speed (docs/KATANA.md chain table)

    @property
    def encoder_range(self) -> tuple[int, int]:
        stop = self.encoder_offset - self.direction * int(
            self.ticks_per_cycle * self.angle_range_deg / 360.0)
        return min(stop, self.encoder_offset), max(stop, self.encoder_offset)

    @property
    def speed_enc_per_tick(self) -> float:
        return self.max_speed_rad_s * self.ticks_per_cycle / (2.0 * math.pi) * 0.01


@dataclass(frozen=True)
class Gripper:
    """Motor 6: the controller's encoder range, and where the fingers are open and touching
    (linear in the finger angle between GRIPPER_CLOSED_RAD and GRIPPER_OPEN_RAD)."""

    encoder_range: tuple[int, int]
    open_enc: int
    touching_enc: int
    max_speed_rad_s: float = 0.719

    @property
    def enc_per_rad(self) -> float:
        return (self.open_enc - self.touching_enc) / (GRIPPER_OPEN_RAD - GRIPPER_CLOSED_RAD)

    @property
    def speed_enc_per_tick(self) -> float:
        return self.max_speed_rad_s * self.enc_per_rad * 0.01

    def encoder_for_width(self, width_m: float) -> int:
        """The encoder at which the finger pads stand ``width_m`` apart (a held block)."""
        angle = finger_angle_for_width(width_m)
        return int(round(self.touching_enc + (angle - GRIPPER_CLOSED_RAD) * self.enc_per_rad))


@dataclass(frozen=True)
class ArmModel:
    katana_type: int
    axes: tuple[Axis, ...]  # motors 1..5
    gripper: Gripper
    master_version: tuple[int, int]  # answered to B: version, revision
    spline_all: bool  # the firmware takes H (one segment for all motors)
    flush: bool  # the firmware takes C 0 32 (flush every move buffer)
    calibrate_all: bool  # the firmware takes C 0 4 (calibrate every motor in one command)

    @property
    def calibrated_encoders(self) -> tuple[int, ...]:
        """Where calibration leaves motors 1..6: each at its encoder offset (the gripper open
        at the top of its range)."""
        return (*(a.encoder_offset for a in self.axes), self.gripper.encoder_range[1])


# Gripper geometry (docs/KATANA.md): the fingers touch at -0.44 rad, are open at 0.30 rad, and
# the jaws stand about 6.3 cm apart at 0 rad. Each finger is a lever from the centre line, so
# the opening is 2 L sin(q + 0.44); 6.3 cm at 0 gives L.
GRIPPER_CLOSED_RAD, GRIPPER_OPEN_RAD = -0.44, 0.30
_OPENING_AT_ZERO_M = 0.063
_LEVER_M = _OPENING_AT_ZERO_M / (2.0 * math.sin(-GRIPPER_CLOSED_RAD))


#: the jaws' opening at the open angle: the widest block the gripper takes
MAX_BLOCK_WIDTH_M = 2.0 * _LEVER_M * math.sin(GRIPPER_OPEN_RAD - GRIPPER_CLOSED_RAD)


def finger_angle_for_width(width_m: float) -> float:
    """Finger angle (rad) at which the jaws stand ``width_m`` apart."""
    if not 0.0 <= width_m <= MAX_BLOCK_WIDTH_M:
        raise ValueError(f"block width {width_m} m outside 0..{MAX_BLOCK_WIDTH_M:.3f} m")
    return math.asin(width_m / (2.0 * _LEVER_M)) + GRIPPER_CLOSED_RAD


# Motors 1..5 of the 450 (katana6M180.cfg and the 6M90A/B files: they differ only in motor 5's
# angle offset, which the controller never sees): ticks per cycle, encoder offset, direction,
# angle range; nominal top speeds.
_AXES_450 = (
    Axis(51200, 31000, 1, 339.0, 2.209),
    Axis(94976, -31000, 1, -132.0, 1.191),
    Axis(47488, -31000, -1, 245.0, 1.191),
    Axis(51200, 31000, 1, 224.0, 2.209),
    Axis(51200, 31000, 1, 336.0, 2.209),
)
# Motor 6 of the 450: KNI's range from offset 31000, 51200 ticks, 329 degrees; the fingers are
# open at 30770 and touch at 12240 (the ROS 1 driver's gripper numbers).
_GRIPPER_450 = Gripper((31000 - int(51200 * 329.0 / 360.0), 31000), 30770, 12240)
# The 300 differs in motor 3 (81408 ticks per cycle) and its gripper encoders (open 31000,
# closed -16768).
_AXES_300 = (_AXES_450[0], _AXES_450[1], Axis(81408, -31000, -1, 245.0, 1.191), *_AXES_450[3:])
_GRIPPER_300 = Gripper((-16768, 31000), 31000, -16768)

# The 400: KNI's 400 configuration files were not at hand; the 450's numbers stand in for them
# (the driver refuses to drive a 400, so no test depends on its ranges).
MODELS = {
    450: ArmModel(450, _AXES_450, _GRIPPER_450, (KNI_PROTOCOL_THRESHOLD, 0), True, True, True),
    400: ArmModel(400, _AXES_450, _GRIPPER_450, (KNI_PROTOCOL_THRESHOLD, 0), True, True, True),
    # a 300 takes single G segments, calibrates motor by motor and has no flush
    300: ArmModel(300, _AXES_300, _GRIPPER_300, (KNI_PROTOCOL_THRESHOLD, 0), False, False, False),
}
VARIANTS = ("6M180", "6M90A", "6M90B")
