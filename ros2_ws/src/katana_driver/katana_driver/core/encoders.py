"""Encoder <-> joint-angle conversion of the Katana, per variant (docs/KATANA.md).

theta_kni = angleOffset - (enc - encoderOffset) * 2 pi / (ticksPerRev * dir); the URDF angle is
theta_kni - pi for motors 1, 3, 4, 5 and theta_kni for motor 2, wrapped to [-pi, pi). This
reproduces the URDF's joint limits. The gripper (motor 6) is linear between 12240 (-0.44 rad,
closed) and 30770 (0.30 rad, open). Angles are the URDF's (what joint_states carries).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from katana_description import models

from .protocol import TICK_S

VARIANTS = ("6M180", "6M90A", "6M90B")
KATANA_TYPES = (300, 400, 450)

#: Katana types the driver refuses at start-up, with the reason. The driver drives only what
#: it drives exactly as the vendor's library (KNI 4.3.0) does; these differ from the 450 in
#: facts the encoder model and the protocol layer do not yet carry per type.
REFUSED_TYPES = {
    300: "KNI's Katana 300 configuration differs from the 450's in encoder facts the driver "
         "does not model (motor 3: 81408 ticks per cycle, not 47488, so a commanded 2.0 rad "
         "would end near 0.24 rad; gripper encoders 31000 open / -16768 closed) and in its "
         "protocol (motor-by-motor calibration, single G segments without H, no flush)",
    400: "KNI drives the Katana 400 with G and G+128 spline segments, not H, and with wider "
         "joint ranges than the 450's that the driver uses",
}

# Joint names and speed limits are katana_description's (one source for the sim and the arm).
ARM_JOINTS = models.ARM_JOINTS
FINGER_JOINTS = models.FINGER_JOINTS
ALL_JOINTS = models.ALL_JOINTS

#: Maximum joint speeds of motors 1..6, rad/s (motor 6: the fingers).
MAX_SPEED = tuple(models.JOINT_MAX_SPEED[j] for j in ARM_JOINTS + FINGER_JOINTS[:1])

GRIPPER_OPEN_ENC, GRIPPER_OPEN_RAD = 30770, models.GRIPPER_OPEN
GRIPPER_CLOSED_ENC, GRIPPER_CLOSED_RAD = 12240, models.GRIPPER_CLOSED


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
    ticks_per_rev: int
    encoder_offset: int
    angle_offset_deg: float
    direction: int  # +1 or -1
    angle_range_deg: float
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


#: Motor 6 (the gripper) as KNI configures it (docs/KATANA.md: 51200 ticks per revolution,
#: encoder offset 31000, angle offset -119.5 deg, direction +, angle range 329 deg): only its
#: encoder range is used, (-15791, 31000); its angle is the linear gripper map below.
GRIPPER_MOTOR = MotorParams(51200, 31000, -119.5, 1, 329.0, 0.0)

#: The default of katana_driver_node's limit_margin_encoders: targets, trajectories and the
#: calibration back-off stay this many encoders inside every motor's encoder range (a real
#: controller is reported to refuse targets within about 200 encoders of its limits). One
#: source with the arm contract and the planner: katana_description.models.
DEFAULT_LIMIT_MARGIN_ENC = models.LIMIT_MARGIN_ENC


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


class EncoderModel:
    """Conversions for one variant; motors are numbered 1..6 as on the wire."""

    def __init__(self, variant: str = "6M180") -> None:
        if variant not in VARIANTS:
            raise ValueError(f"variant '{variant}' not one of {', '.join(VARIANTS)}")
        self.variant = variant
        m5_offset = -171.5 if variant == "6M90B" else 8.5
        pi = math.pi
        ticks = [models.ENCODERS_PER_REV[j] for j in ARM_JOINTS]
        self.motors = (
            MotorParams(ticks[0], 31000, 6.65, 1, 339.0, pi),
            MotorParams(ticks[1], -31000, 124.25, 1, -132.0, 0.0),
            MotorParams(ticks[2], -31000, 52.7, -1, 245.0, pi),
            MotorParams(ticks[3], 31000, 63.5, 1, 224.0, pi),
            MotorParams(ticks[4], 31000, m5_offset, 1, 336.0, pi),
        )

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
    @staticmethod
    def gripper_encoder_to_angle(enc: float) -> float:
        frac = (enc - GRIPPER_CLOSED_ENC) / (GRIPPER_OPEN_ENC - GRIPPER_CLOSED_ENC)
        return GRIPPER_CLOSED_RAD + frac * (GRIPPER_OPEN_RAD - GRIPPER_CLOSED_RAD)

    @staticmethod
    def gripper_angle_to_encoder(angle: float) -> float:
        frac = (angle - GRIPPER_CLOSED_RAD) / (GRIPPER_OPEN_RAD - GRIPPER_CLOSED_RAD)
        return GRIPPER_CLOSED_ENC + frac * (GRIPPER_OPEN_ENC - GRIPPER_CLOSED_ENC)

    @staticmethod
    def gripper_encoder_range() -> tuple[int, int]:
        return GRIPPER_MOTOR.encoder_range

    @staticmethod
    def gripper_speed_limit_enc() -> float:
        enc_per_rad = (GRIPPER_OPEN_ENC - GRIPPER_CLOSED_ENC) / (
            GRIPPER_OPEN_RAD - GRIPPER_CLOSED_RAD
        )
        return MAX_SPEED[5] * enc_per_rad * TICK_S

    # ------------------------------------------------------------------ all motors
    def encoders_to_joint_positions(self, encoders: list[int] | tuple[int, ...]) -> list[float]:
        """Six encoder values -> the seven joint_states positions (fingers equal)."""
        arm = [self.encoder_to_angle(i + 1, encoders[i]) for i in range(5)]
        finger = self.gripper_encoder_to_angle(encoders[5])
        return arm + [finger, finger]
