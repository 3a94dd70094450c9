"""katana_driver_node's parameters: live ones are applied at once, the others are read-only.

Live: poll_rate, reconnect_period, max_trajectory_s and the goal defaults (tolerances, settle
and stall times): they change how the next poll or goal runs. Read-only: what the link, the
arm model and the controller's set-up were opened with (a change would need a reconnection),
and autostart (whether the node brings itself to active or waits for its transitions).
"""

from __future__ import annotations

from katana_common.params import Param
from katana_description import models

from katana_driver.core.encoders import DEFAULT_LIMIT_MARGIN_ENC, refusal_of, variant_of
from katana_driver.core.protocol import KNI_MAX_ACCELERATION, KNI_MAX_VELOCITY

PARAMS = (
    Param("model", models.DEFAULT_MODEL, "arm model TYPE_VARIANT (the angled 6M90A/B grippers "
          "are not modelled by katana_description)", choices=tuple(sorted(models.MODELS))),
    Param("transport", "tcp", "link: tcp (400/450) or serial (300)", choices=("tcp", "serial")),
    Param("host", "192.168.1.1", "controller address (TCP)", nonempty=True),
    Param("port", 5566, "controller TCP port", low=1, high=65535),
    Param("serial_device", "/dev/ttyUSB0", "serial device (Katana 300)", nonempty=True),
    Param("autostart", True, "bring the driver to active (configure, activate) at start and "
          "again after an error, retrying configure every reconnect_period while the controller "
          "does not answer, as nav2's lifecycle manager does; false: it stays unconfigured "
          "until a lifecycle transition is requested (launch events, ros2 lifecycle set)"),
    Param("calibrate_on_startup", True, "calibrate when the arm is not (after every power-on)"),
    Param("calibration_timeout", 120.0, "longest calibration run, s", low=1.0, high=600.0),
    Param("poll_rate", 25.0, "joint_states polling rate, Hz", low=1.0, high=50.0, live=True),
    Param("timeout", 0.5, "reply timeout per attempt, s", low=0.05, high=10.0),
    Param("retries", 3, "re-sends of an idempotent request on a lost reply", low=0, high=10),
    Param("reconnect_period", 1.0, "s between reconnections", low=0.1, high=60.0, live=True),
    Param("collision_detection", True, "let the controller stop the arm on a collision"),
    Param("limit_margin_encoders", DEFAULT_LIMIT_MARGIN_ENC, "encoders that targets, "
          "trajectories and the calibration back-off stay inside every motor's encoder range (a "
          "real controller is reported to refuse targets within about 200 of its limits); goals "
          "closer to a limit are refused", low=0, high=2000),
    Param("speed_limits", [KNI_MAX_VELOCITY] * 6, "speed limit of motors 1..6 sent at start-up "
          "(S sub-command 3), encoders per 10 ms; the planner keeps to it and to the joint speed "
          "limits. Default 180: KNI_MAX_VELOCITY of the ROS 1 katana node (katana_constants.h)",
          low=1, high=KNI_MAX_VELOCITY, length=6),
    Param("acceleration_limits", [KNI_MAX_ACCELERATION] * 6, "acceleration limit of motors "
          "1..6 sent at start-up (S sub-command 4), encoders per (10 ms)^2; trajectories that "
          "need more are refused. Default 2: KNI_MAX_ACCELERATION of the ROS 1 katana node "
          "(katana_constants.h: 'acceleration limit = 1 or 2')", low=1, high=2, length=6),
    Param("max_trajectory_s", 60.0, "longest trajectory accepted, s", low=1.0, high=600.0,
          live=True),
    Param("goal_tolerance", 0.01, "default final position tolerance, rad", low=0.001, high=0.5,
          live=True),
    Param("goal_time_tolerance", 1.0, "default time to settle after the end, s", low=0.0,
          high=30.0, live=True),
    Param("gripper_tolerance", 0.01, "gripper position tolerance, rad", low=0.001, high=0.2,
          live=True),
    Param("gripper_stall_time", 0.2, "fingers still this long short of the goal = holding, s "
          "(0.2: two or three polls on the arm, 80 ms each with the status read)",
          low=0.1, high=10.0, live=True),
)


def cross_check(values) -> str | None:
    refusal = refusal_of(values["model"])
    if refusal:
        return f"parameter 'model' = {values['model']!r}: {refusal}"
    kind, _ = variant_of(values["model"])
    if (values["transport"] == "serial") != (kind == 300):
        return (f"parameter 'transport' = {values['transport']!r} does not fit model "
                f"{values['model']!r}: the Katana 300 uses serial, the 400/450 tcp")
    return None
