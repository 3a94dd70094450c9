"""Encoder <-> joint-angle conversion of the Katana, per arm model (docs/KATANA.md).

KNI's conversion (its enc2rad): theta_kni = angleOffset - (enc - encoderOffset) * 2 pi /
(encodersPerCycle * rotationDirection); the URDF angle is theta_kni - pi for motors 1, 3, 4, 5
and theta_kni for motor 2, wrapped to [-pi, pi) (the ROS 1 node's KNIConverter). A motor's
encoder range runs from encoderOffset to KNI's encoder stop, encoderOffset - rotationDirection *
int(encodersPerCycle * angleRange / 360). The gripper (motor 6) is linear between the cfg's
closeEncoders (-0.44 rad) and openEncoders (0.30 rad). Angles are the URDF's (joint_states').
Each model's numbers are in KNI_CONFIGS, with the file they come from.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from katana_description import models

from .protocol import TICK_S

VARIANTS = ("6M180", "6M90A", "6M90B")
KATANA_TYPES = (300, 400, 450)

#: Katana types the driver refuses at start-up, with the reason. The driver drives only what
#: it drives exactly as the vendor's library (KNI 4.3.0) does. Both have an encoder model
#: (KNI_CONFIGS) that a driver of their protocol can use; the protocol is what differs.
REFUSED_TYPES = {
    300: "KNI drives the Katana 300 motor by motor (it calibrates one motor at a time and "
         "sends single G segments, never H), and its flush of the move buffers moves a 300 "
         "to 'a weird configuration' (the ROS 1 driver skips it); this driver calibrates all "
         "motors at once, plays H segments and flushes on every stop",
    400: "KNI drives the Katana 400 with per-motor G segments started by G+128, not with the "
         "H segments this driver plays",
}

# Joint names and speed limits are katana_description's (one source for the sim and the arm).
ARM_JOINTS = models.ARM_JOINTS
FINGER_JOINTS = models.FINGER_JOINTS
ALL_JOINTS = models.ALL_JOINTS

#: Maximum joint speeds of motors 1..6, rad/s (motor 6: the fingers).
MAX_SPEED = tuple(models.JOINT_MAX_SPEED[j] for j in ARM_JOINTS + FINGER_JOINTS[:1])

GRIPPER_OPEN_RAD = models.GRIPPER_OPEN
GRIPPER_CLOSED_RAD = models.GRIPPER_CLOSED


def variant_of(model_name: str) -> tuple[int, str]:
    """(Katana type, gripper variant) of an arm model name such as "450_6m180"."""
    kind, _, variant = model_name.partition("_")
    if not kind.isdigit() or int(kind) not in KATANA_TYPES or variant.upper() not in VARIANTS:
        raise ValueError(f"arm model '{model_name}' is not TYPE_VARIANT with TYPE in "
                         f"{KATANA_TYPES} and VARIANT in {VARIANTS}")
    return int(kind), variant.upper()


def refusal_of(model_name: str) -> str | None:
    """Why the driver refuses to drive `model_name`, or None when it drives it as KNI does."""
    kind, _ = variant_of(model_name)
    reason = REFUSED_TYPES.get(kind)
    return None if reason is None else f"the Katana {kind} is refused: {reason}"


@dataclass(frozen=True)
class MotorParams:
    """One motor's [MOT[i]] numbers of a KNI configuration file."""

    ticks_per_rev: int  # encodersPerCycle
    encoder_offset: int  # encoderOffset: the encoder at the calibration stop
    angle_offset_deg: float  # angleOffset: KNI's angle at the calibration stop
    direction: int  # rotationDirection, +1 or -1
    angle_range_deg: float  # angleRange: signed, from the calibration stop
    urdf_shift: float  # theta_urdf = theta_kni - urdf_shift

    @property
    def encoder_stop(self) -> int:
        """Encoder at the far end of the range (KNI truncates towards zero)."""
        span = int(self.ticks_per_rev * self.angle_range_deg / 360.0)
        return self.encoder_offset - self.direction * span

    @property
    def encoder_range(self) -> tuple[int, int]:
        a, b = self.encoder_offset, self.encoder_stop
        return (min(a, b), max(a, b))

    @property
    def enc_per_rad(self) -> float:
        """d enc / d theta (signed)."""
        return -self.ticks_per_rev * self.direction / (2.0 * math.pi)


@dataclass(frozen=True)
class KniConfig:
    """One Katana model's encoder facts as KNI configures them (docs/KATANA.md, per model)."""

    model: str  # the driver's model name, e.g. "450_6m180"
    source: str  # where the numbers come from
    motors: tuple[MotorParams, ...]  # motors 1..5
    gripper_open_enc: int  # [GRIPPER] openEncoders
    gripper_closed_enc: int  # [GRIPPER] closeEncoders
    gripper_range: tuple[int, int]  # motor 6's encoder range

    def with_variant(self, variant: str) -> KniConfig:
        """The 6M90B mounts motor 5 half a turn round: its angle offset is 8.5 - 180 degrees
        (KNI's katana6M90B cfgs); the 6M180 and 6M90A share the 6M180's."""
        if variant != "6M90B":
            return self
        m5 = self.motors[4]
        turned = MotorParams(m5.ticks_per_rev, m5.encoder_offset, m5.angle_offset_deg - 180.0,
                             m5.direction, m5.angle_range_deg, m5.urdf_shift)
        return KniConfig(self.model, self.source, (*self.motors[:4], turned),
                         self.gripper_open_enc, self.gripper_closed_enc, self.gripper_range)


_PI = math.pi


def _arm(ticks: tuple[int, ...], ranges: tuple[float, ...]) -> tuple[MotorParams, ...]:
    """Motors 1..5 of a 6M180: the encoder offsets (+-31000), angle offsets (6.65, 124.25,
    52.7, 63.5, 8.5 degrees) and directions (motor 3 negative) every KNI 6M180 cfg shares,
    with the model's ticks per cycle and angle ranges."""
    offsets = (31000, -31000, -31000, 31000, 31000)
    angle_offsets = (6.65, 124.25, 52.7, 63.5, 8.5)
    directions = (1, 1, -1, 1, 1)
    shifts = (_PI, 0.0, _PI, _PI, _PI)
    return tuple(MotorParams(*row) for row in zip(ticks, offsets, angle_offsets, directions,
                                                  ranges, shifts, strict=True))


#: Motor 6 (the gripper) of the Katana 400/450 cfgs: 51200 ticks per cycle, encoder offset
#: 31000, angle offset -119.5 degrees, direction +, angle range 329 degrees: its encoder
#: range (-15791, 31000) is the gripper's; its angle is the linear gripper map.
GRIPPER_MOTOR = MotorParams(51200, 31000, -119.5, 1, 329.0, 0.0)

_TICKS_450 = tuple(models.ENCODERS_PER_REV[j] for j in ARM_JOINTS)  # 51200, 94976, 47488, ...

#: Every model's encoder facts, keyed by the model parameter's values (katana_description).
KNI_CONFIGS: dict[str, KniConfig] = {
    # KNI 4.3.0 configfiles450/katana6M180.cfg: ticks per cycle are katana_description's
    # (ENCODERS_PER_REV), ranges 339, -132, 245, 224, 336 degrees; they reproduce the ROS 1
    # URDF's limits (katana_description.models.JOINT_LIMITS, a test keeps them equal). Gripper
    # openEncoders 30770, closeEncoders 12240 (the ROS 1 node's KNI_GRIPPER_OPEN_ANGLE
    # -2.057443 and KNI_GRIPPER_CLOSED_ANGLE 0.2165299 rad through motor 6's numbers).
    "450_6m180": KniConfig(
        "450_6m180", "KNI 4.3.0 configfiles450/katana6M180.cfg",
        _arm(_TICKS_450, (339.0, -132.0, 245.0, 224.0, 336.0)),
        30770, 12240, GRIPPER_MOTOR.encoder_range),
    # Katana 4XX 6M180 of KNI 4.3.0 (configfiles400/katana6M180.cfg): the 450's ticks per
    # cycle, wider ranges 346, -140, 250, 230, 342 degrees (KNI 4.3.0's analytical kinematics
    # for the 6M180, kinematics6M180.cpp, Kinematics6M180::initialize: angle offsets and stops
    # in rad, e.g. motor 1 0.116064 .. 6.154904). Gripper as the 450's. Unconfirmed against the
    # cfg file itself (docs/hardware.md).
    "400_6m180": KniConfig(
        "400_6m180", "KNI 4.3.0 configfiles400/katana6M180.cfg (kinematics6M180.cpp)",
        _arm(_TICKS_450, (346.0, -140.0, 250.0, 230.0, 342.0)),
        30770, 12240, GRIPPER_MOTOR.encoder_range),
    # KNI configfiles300/katana6M180.cfg: motor 3 has 81408 ticks per cycle, not 47488;
    # ranges 346.7, -143.0, 250.0, 232.7, 342.8 degrees (the Katana 300 numbers of KNI 3.9.2,
    # as quoted by the Golem Katana driver's encoder test). Gripper openEncoders 31000,
    # closeEncoders -16768: motor 6 spans (-16768, 31000). Ranges unconfirmed against the
    # 4.3.0 cfg file itself (docs/hardware.md).
    "300_6m180": KniConfig(
        "300_6m180", "KNI configfiles300/katana6M180.cfg",
        _arm((51200, 94976, 81408, 51200, 51200), (346.7, -143.0, 250.0, 232.7, 342.8)),
        31000, -16768, (-16768, 31000)),
}

_CONFIG_OF_TYPE = {int(name.split("_")[0]): cfg for name, cfg in KNI_CONFIGS.items()}

#: The default of katana_driver_node's limit_margin_encoders: targets, trajectories and the
#: calibration back-off stay this many encoders inside every motor's encoder range (a real
#: controller is reported to refuse targets within about 200 encoders of its limits). One
#: source with the arm contract and the planner: katana_description.models.
DEFAULT_LIMIT_MARGIN_ENC = models.LIMIT_MARGIN_ENC


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


class EncoderModel:
    """Conversions for one Katana type and gripper variant; motors are numbered 1..6 as on
    the wire. ``EncoderModel.for_model(name)`` builds the one of a model parameter's value."""

    def __init__(self, variant: str = "6M180", katana_type: int = 450) -> None:
        if variant not in VARIANTS:
            raise ValueError(f"variant '{variant}' not one of {', '.join(VARIANTS)}")
        if katana_type not in _CONFIG_OF_TYPE:
            raise ValueError(f"Katana type {katana_type} not one of "
                             f"{', '.join(map(str, sorted(_CONFIG_OF_TYPE)))}")
        self.variant = variant
        self.katana_type = katana_type
        self.config = _CONFIG_OF_TYPE[katana_type].with_variant(variant)
        self.motors = self.config.motors

    @classmethod
    def for_model(cls, model_name: str) -> EncoderModel:
        """The encoder model of an arm model name such as "300_6m180" (its Katana type's KNI
        numbers, its gripper variant)."""
        kind, variant = variant_of(model_name)
        return cls(variant, kind)

    # ------------------------------------------------------------------ arm motors 1..5
    def params(self, motor: int) -> MotorParams:
        if not 1 <= motor <= 5:
            raise ValueError(f"arm motor {motor} outside 1..5")
        return self.motors[motor - 1]

    def encoder_to_angle(self, motor: int, enc: float) -> float:
        m = self.params(motor)
        theta_kni = math.radians(m.angle_offset_deg) + (enc - m.encoder_offset) / m.enc_per_rad
        return _wrap(theta_kni - m.urdf_shift)

    def angle_to_encoder(self, motor: int, angle: float) -> float:
        """Encoder value of ``angle``; of the 2 pi branches, the one in (or nearest) the range."""
        m = self.params(motor)
        lo, hi = m.encoder_range
        best, best_dist = 0.0, math.inf
        for k in (-1, 0, 1, 2):
            theta_kni = angle + m.urdf_shift + 2.0 * math.pi * k
            enc = m.encoder_offset + (theta_kni - math.radians(m.angle_offset_deg)) * m.enc_per_rad
            dist = max(lo - enc, enc - hi, 0.0)
            if dist < best_dist:
                best, best_dist = enc, dist
        return best

    def encoder_range(self, motor: int) -> tuple[int, int]:
        return self.params(motor).encoder_range

    def safe_range(self, motor: int, margin: int) -> tuple[int, int]:
        """The encoder range of motor 1..6 less ``margin`` at both ends."""
        lo, hi = self.encoder_range(motor) if motor <= 5 else self.gripper_encoder_range()
        return lo + margin, hi - margin

    def backed_off_stops(self, backoff_enc: int) -> list[int]:
        """Encoders of motors 1..5 ``backoff_enc`` inside their calibration stops (the encoder
        offset, where calibration leaves each motor), towards the other end of the range."""
        targets = []
        for motor in range(1, 6):
            m = self.params(motor)
            inward = 1 if m.encoder_stop > m.encoder_offset else -1
            targets.append(m.encoder_offset + inward * int(backoff_enc))
        return targets

    def calibration_pose(self, backoff_rad: float = 0.0) -> list[float]:
        """Angles of motors 1..5 at their calibration stops, moved ``backoff_rad`` inwards."""
        pose = []
        for motor in range(1, 6):
            stop = self.encoder_to_angle(motor, self.params(motor).encoder_offset)
            lower, upper = self.joint_limits(motor)
            inward = 1.0 if abs(stop - lower) < abs(stop - upper) else -1.0
            pose.append(_wrap(stop + inward * backoff_rad))
        return pose

    def joint_limits(self, motor: int) -> tuple[float, float]:
        """(lower, upper) in rad; upper may exceed pi when the range crosses the wrap (6M90B)."""
        lo_enc, hi_enc = self.encoder_range(motor)
        a = self.encoder_to_angle(motor, lo_enc)
        b = self.encoder_to_angle(motor, hi_enc)
        lower, upper = min(a, b), max(a, b)
        span = abs(hi_enc - lo_enc) / abs(self.params(motor).enc_per_rad)
        if abs((upper - lower) - span) > 1e-6:  # the range wraps around +-pi
            lower, upper = upper, upper + span
        return lower, upper

    def speed_to_encoder(self, motor: int, rad_per_s: float) -> float:
        """Joint speed in encoders per 10 ms tick (signed)."""
        return rad_per_s * self.params(motor).enc_per_rad * TICK_S

    def speed_limit_enc(self, motor: int) -> float:
        """The joint's speed limit in encoders per tick (positive)."""
        return abs(self.speed_to_encoder(motor, MAX_SPEED[motor - 1]))

    # ------------------------------------------------------------------ gripper, motor 6
    def gripper_encoder_to_angle(self, enc: float) -> float:
        c = self.config
        frac = (enc - c.gripper_closed_enc) / (c.gripper_open_enc - c.gripper_closed_enc)
        return GRIPPER_CLOSED_RAD + frac * (GRIPPER_OPEN_RAD - GRIPPER_CLOSED_RAD)

    def gripper_angle_to_encoder(self, angle: float) -> float:
        c = self.config
        frac = (angle - GRIPPER_CLOSED_RAD) / (GRIPPER_OPEN_RAD - GRIPPER_CLOSED_RAD)
        return c.gripper_closed_enc + frac * (c.gripper_open_enc - c.gripper_closed_enc)

    def gripper_encoder_range(self) -> tuple[int, int]:
        return self.config.gripper_range

    def gripper_speed_limit_enc(self) -> float:
        c = self.config
        enc_per_rad = (c.gripper_open_enc - c.gripper_closed_enc) / (
            GRIPPER_OPEN_RAD - GRIPPER_CLOSED_RAD
        )
        return MAX_SPEED[5] * enc_per_rad * TICK_S

    # ------------------------------------------------------------------ all motors
    def encoders_to_joint_positions(self, encoders: list[int] | tuple[int, ...]) -> list[float]:
        """Six encoder values -> the seven joint_states positions (fingers equal)."""
        arm = [self.encoder_to_angle(i + 1, encoders[i]) for i in range(5)]
        finger = self.gripper_encoder_to_angle(encoders[5])
        return arm + [finger, finger]
