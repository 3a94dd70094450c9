"""Katana arm facts (docs/KATANA.md) shared by the URDF generator, the kinematics and the sim.

ROS-free. One place for link lengths, limits, speeds and masses, so the URDF and the closed-form
kinematics cannot drift apart; the kinematics tests still check the two against PyBullet's own
forward kinematics of the generated URDF.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

ARM_JOINTS: tuple[str, ...] = (
    "katana_motor1_pan_joint",
    "katana_motor2_lift_joint",
    "katana_motor3_lift_joint",
    "katana_motor4_lift_joint",
    "katana_motor5_wrist_roll_joint",
)
FINGER_JOINTS: tuple[str, ...] = ("katana_r_finger_joint", "katana_l_finger_joint")
ALL_JOINTS: tuple[str, ...] = ARM_JOINTS + FINGER_JOINTS

#: (lower, upper) rad, from the ROS 1 URDF (KNI encoder ranges).
JOINT_LIMITS: dict[str, tuple[float, float]] = {
    "katana_motor1_pan_joint": (-3.025528, 2.891097),
    "katana_motor2_lift_joint": (-0.135228, 2.168572),
    "katana_motor3_lift_joint": (-2.221804, 2.054223),
    "katana_motor4_lift_joint": (-2.033309, 1.876133),
    "katana_motor5_wrist_roll_joint": (-2.993240, 2.870985),
    "katana_r_finger_joint": (-0.44, 0.30),
    "katana_l_finger_joint": (-0.44, 0.30),
}
#: rad/s; motor 3 was measured at half the nominal speed.
JOINT_MAX_SPEED: dict[str, float] = {
    "katana_motor1_pan_joint": 2.208932,
    "katana_motor2_lift_joint": 1.190799,
    "katana_motor3_lift_joint": 1.190799,
    "katana_motor4_lift_joint": 2.208932,
    "katana_motor5_wrist_roll_joint": 2.208932,
    "katana_r_finger_joint": 0.718834,
    "katana_l_finger_joint": 0.718834,
}
#: Encoder ticks per motor revolution of the arm joints (KNI's Katana 450 configuration,
#: docs/KATANA.md): the one source of the driver's encoder model and of the limits below.
ENCODERS_PER_REV: dict[str, int] = {
    "katana_motor1_pan_joint": 51200,
    "katana_motor2_lift_joint": 94976,
    "katana_motor3_lift_joint": 47488,
    "katana_motor4_lift_joint": 51200,
    "katana_motor5_wrist_roll_joint": 51200,
}
#: The controller's time step, s: spline durations, speed and acceleration limits count in it.
CONTROL_TICK_S = 0.01
#: Speed limit every motor gets at start-up, encoders per tick: KNI_MAX_VELOCITY of the ROS 1
#: katana node (katana_constants.h, "velocity limit <= 180 [enc / 10 ms]").
KNI_MAX_VELOCITY = 180
#: Acceleration limit every motor gets at start-up, encoders per tick squared:
#: KNI_MAX_ACCELERATION of the ROS 1 katana node (katana_constants.h, "1 or 2").
KNI_MAX_ACCELERATION = 2
#: Encoders every target stays inside each motor's encoder range (a real controller is reported
#: to refuse targets within about 200 encoders of its limits). The default of the driver's
#: limit_margin_encoders, and what the arm contract (both backends) and the planner keep.
LIMIT_MARGIN_ENC = 200


def encoders_per_rad(joint: str) -> float:
    """|d encoder / d angle| of an arm joint."""
    return ENCODERS_PER_REV[joint] / (2.0 * math.pi)


def accel_limit_rad_s2(joint: str, accel_enc: float = KNI_MAX_ACCELERATION) -> float:
    """An arm joint's acceleration limit in rad/s^2 from encoders per tick squared."""
    return accel_enc / (encoders_per_rad(joint) * CONTROL_TICK_S**2)


def inner_limits(limits: dict[str, tuple[float, float]],
                 margin_enc: float = LIMIT_MARGIN_ENC) -> dict[str, tuple[float, float]]:
    """The arm joints' limits shrunk by ``margin_enc`` encoders at both ends (the fingers'
    limits as they are: the gripper's own map keeps them inside its motor's range)."""
    out = dict(limits)
    for joint in ARM_JOINTS:
        lo, hi = limits[joint]
        d = margin_enc / encoders_per_rad(joint)
        out[joint] = (lo + d, hi - d)
    return out


#: rad/s^2 each arm joint may accelerate at under KNI_MAX_ACCELERATION (motor 2, with the most
#: encoders per radian, least: about 1.32; motors 1, 4, 5 about 2.45; motor 3 about 2.65).
JOINT_MAX_ACCEL: dict[str, float] = {j: accel_limit_rad_s2(j) for j in ARM_JOINTS}

#: N m the simulated motors may use. Not the URDF's effort limits (measured with gravity off):
#: holding the arm horizontal needs about 6.9 N m at motor 2, so these leave a wide margin.
SIM_MOTOR_TORQUE: dict[str, float] = {
    "katana_motor1_pan_joint": 40.0,
    "katana_motor2_lift_joint": 60.0,
    "katana_motor3_lift_joint": 40.0,
    "katana_motor4_lift_joint": 20.0,
    "katana_motor5_wrist_roll_joint": 5.0,
    "katana_r_finger_joint": 1.0,
    "katana_l_finger_joint": 1.0,
}

#: N m s / rad of viscous damping per joint (the URDF's <dynamics damping>). Bullet applies it
#: explicitly, which is stable only while damping * dt < 2 * I, I being the joint's inertia. At
#: 0.05 like the arm's, the wrist (I about 9.2e-5 kg m^2) and each finger (4.6e-5) were beyond
#: that at 240 Hz: a finger knocked by a falling block went into a lasting +-52 rad/s
#: oscillation, and the arm never came to rest. 0.002 keeps damping * dt / I under 0.75 down
#: to the sim's slowest physics rate (60 Hz); the motors' own control does the rest.
JOINT_DAMPING: dict[str, float] = {
    "katana_motor1_pan_joint": 0.05,
    "katana_motor2_lift_joint": 0.05,
    "katana_motor3_lift_joint": 0.05,
    "katana_motor4_lift_joint": 0.05,
    "katana_motor5_wrist_roll_joint": 0.002,
    "katana_r_finger_joint": 0.002,
    "katana_l_finger_joint": 0.002,
}

BASE_HEIGHT = 0.2015  # table (base link) to the motor 2 axis
LINK2 = 0.19  # motor 2 -> motor 3
LINK3 = 0.139  # motor 3 -> motor 4
WRIST_TO_GRIPPER = 0.0323  # motor 5 joint -> gripper link (ROS 1 URDF)

# Gripper: each finger is a lever of length FINGER_LEVER from a pivot on the gripper's centre line,
# at angle FINGER_ANGLE0 + q from the approach axis. This reproduces docs/KATANA.md's jaw openings:
# touching at -0.44 rad, about 6.3 cm at 0 and 9.7 cm at 0.30.
FINGER_ANGLE0 = 0.44
FINGER_LEVER = 0.0737
#: finger angle at which the pads are parallel (a 4 cm block); pads are flat boxes at the tips
FINGER_PAD_PARALLEL_AT = -0.165
FINGER_PAD_LENGTH = 0.026  # along the approach axis
FINGER_PAD_THICKNESS = 0.008
FINGER_PAD_WIDTH = 0.022

# Masses (kg), docs/KATANA.md.
MASSES: dict[str, float] = {
    "base": 1.405,
    "link1": 0.748,
    "link2": 0.802,
    "link3": 0.792,
    "link4": 0.692,
    "link5": 0.256,
    "gripper": 0.055,
    "finger": 0.025,
}

#: Parked behind the base, gripper pointing down 0.125 m above the table, out of the overhead
#: camera's view (the ROS 1 driver's park pose leaves the forearm in the default image). It is
#: also the pick-and-place transit pose at that pan angle, so leaving it needs no extra move.
PARK_POSE: tuple[float, ...] = (-3.0, 1.6447, -1.3766, 1.8389, 0.0)
GRIPPER_OPEN = 0.30
GRIPPER_CLOSED = -0.44


@dataclass(frozen=True)
class ArmModel:
    """Lengths that differ between Katana types (6M180 gripper in line with the wrist)."""

    name: str
    link4: float  # motor 4 -> motor 5
    tool: float  # motor 5 -> tool frame (the point between the finger pads)
    limits: dict[str, tuple[float, float]] = field(default_factory=lambda: dict(JOINT_LIMITS))

    @property
    def finger_pivot(self) -> float:
        """Distance from the gripper link origin to the finger pivots along the approach axis."""
        reach = FINGER_LEVER * math.cos(FINGER_ANGLE0 + FINGER_PAD_PARALLEL_AT)
        return self.tool - WRIST_TO_GRIPPER - reach


MODELS: dict[str, ArmModel] = {
    "450_6m180": ArmModel("450_6m180", link4=0.1473, tool=0.1555),
    "400_6m180": ArmModel("400_6m180", link4=0.1523, tool=0.166),
    "300_6m180": ArmModel("300_6m180", link4=0.1523, tool=0.166),
}
DEFAULT_MODEL = "450_6m180"
#: Types the Katana family has that are not modelled here (angled 90 degree grippers).
UNMODELLED = ("450_6m90a", "450_6m90b")


def get_model(name: str) -> ArmModel:
    """The arm model called `name`; a clear ValueError for the angled-gripper variants."""
    key = name.lower()
    if key in MODELS:
        return MODELS[key]
    if key in UNMODELLED:
        raise ValueError(
            f"katana model '{name}': the angled 6M90A/6M90B grippers are not modelled yet; "
            f"use one of {sorted(MODELS)}"
        )
    raise ValueError(f"katana model '{name}' is unknown; use one of {sorted(MODELS)}")


def finger_opening(q: float) -> float:
    """Distance between the inner faces of the two pads at finger angle q (m)."""
    return 2.0 * FINGER_LEVER * math.sin(FINGER_ANGLE0 + q)


def finger_angle_for_opening(width: float) -> float:
    """Finger angle at which the pads are `width` apart (inverse of finger_opening)."""
    s = max(-1.0, min(1.0, width / (2.0 * FINGER_LEVER)))
    return math.asin(s) - FINGER_ANGLE0


# Blocks and table (shared scene defaults).
BLOCK_SIZE: tuple[float, float, float] = (0.04, 0.04, 0.03)


def stands_upright(size) -> bool:
    """A block's resting extents (x, y along its yaw, z vertical) show it on its largest face.

    Only an upright block is a support or a block to move: one that fell onto its side is
    taller than a level and narrower than the gripper expects (perception reports its size).
    """
    return float(size[2]) <= min(float(size[0]), float(size[1])) + 1e-9


#: how far a block's own z axis may lean from the vertical and the block still lie flat
FLAT_TOLERANCE_RAD = math.radians(10.0)


def lies_flat(qx: float, qy: float, qz: float, qw: float) -> bool:
    """A block's orientation (unit quaternion) puts its z axis near the vertical, up or down:
    it rests on its top or bottom face, not on a side and not leaning (ground truth only)."""
    return abs(1.0 - 2.0 * (qx * qx + qy * qy)) >= math.cos(FLAT_TOLERANCE_RAD)


BLOCK_MASS = 0.04
COLOURS: dict[str, tuple[float, float, float, float]] = {
    "red": (0.85, 0.10, 0.10, 1.0),
    "green": (0.10, 0.70, 0.15, 1.0),
    "blue": (0.10, 0.20, 0.90, 1.0),
    "yellow": (0.95, 0.85, 0.10, 1.0),
    "orange": (1.00, 0.50, 0.05, 1.0),
    "purple": (0.50, 0.15, 0.65, 1.0),
    "cyan": (0.10, 0.85, 0.90, 1.0),
    "magenta": (0.95, 0.15, 0.75, 1.0),
}
DEFAULT_COLOURS: tuple[str, ...] = tuple(COLOURS)
TABLE_COLOUR = (0.78, 0.78, 0.78, 1.0)
TABLE_SIZE = (1.0, 1.0, 0.03)
TABLE_CENTRE_XY = (0.15, 0.0)
#: Overhead camera: optical centre in the world frame (m) and fixed-axis roll, pitch, yaw (rad)
#: of camera_optical_frame, looking straight down with image x along world -y.
CAMERA_POSITION: tuple[float, float, float] = (0.22, 0.0, 0.75)
CAMERA_RPY: tuple[float, float, float] = (math.pi, 0.0, -math.pi / 2)
