"""The driver's end of a gripper goal (the gripper contract's judge with the driver's default
tolerance and stall time, fed as core.motion feeds it: positions polled at the default
poll_rate, speeds from consecutive polls, "at rest" from the motor's status) against the
emulator's motor model of the fingers (trapezoidal moves at KNI's speed and acceleration
limits; closing fingers stop on a block). ROS-free, on a simulated clock."""

from __future__ import annotations

from hypothesis import assume, given, settings
from hypothesis import strategies as st
from katana_description import arm_contract as ac
from katana_description import gripper_contract as gc
from katana_description import models as m
from katana_driver.core import protocol as p
from katana_driver.core.encoders import EncoderModel
from katana_driver.driver_params import PARAMS
from katana_emulator.emulator import KatanaModel

DEFAULTS = {param.name: param.default for param in PARAMS}
ENC = EncoderModel()


def _run(start: float, goal: float, block_enc: int | None):
    """Move the emulated fingers to `start`, then command `goal` and judge each poll until the
    judge answers: (outcome, simulated s of the verdict, s when the fingers last moved)."""
    clock = [0.0]
    model = KatanaModel(calibrated=True, clock=lambda: clock[0])
    for sub, value in ((p.SUB_SPEED_LIMIT, DEFAULTS["speed_limits"][5]),
                       (p.SUB_ACCEL_LIMIT, DEFAULTS["acceleration_limits"][5])):
        model.handle(p.set_limit(6, sub, value, value).payload)
    fingers = model.motors[5]

    def command(angle: float) -> None:
        enc = int(round(ENC.gripper_angle_to_encoder(angle)))
        model.handle(p.motor_command(6, p.FLAG_MOVE, enc).payload)

    command(start)
    clock[0] += 5.0
    model.advance()
    model.gripper_stall_at = block_enc
    contract = ac.ArmContract(gripper_tolerance_rad=DEFAULTS["gripper_tolerance"],
                              gripper_stall_time_s=DEFAULTS["gripper_stall_time"])
    here = ENC.gripper_encoder_to_angle(fingers.pos)
    judge = gc.GripperJudge(gc.GripperGoal(goal), here, contract)
    command(goal)
    t0 = clock[0]
    period = 1.0 / DEFAULTS["poll_rate"]
    last_move, before = t0, fingers.pos
    while True:
        clock[0] += period
        model.advance()
        if fingers.pos != before:
            last_move = clock[0]
        before = fingers.pos
        angle = ENC.gripper_encoder_to_angle(fingers.pos)
        speed = (angle - here) / period
        here = angle
        out = judge.check(clock[0] - t0, angle, speed,
                          at_rest=fingers.status not in p.MOVING_STATUSES)
        if out.done:
            return out, clock[0] - t0, last_move - t0


_opening = st.floats(m.GRIPPER_CLOSED + 0.05, m.GRIPPER_OPEN)


@settings(max_examples=40, deadline=None)
@given(start=_opening, goal=_opening)
def test_a_free_move_is_reached_never_stalled(start, goal):
    # a move to where the fingers already are: the emulator's motor stays 'moving' (a real
    # controller holds), which the judge can only call stalled
    assume(abs(goal - start) > 2 * DEFAULTS["gripper_tolerance"])
    out, _, _ = _run(start, goal, None)
    assert out.reached_goal and not out.stalled
    assert abs(out.position - goal) <= DEFAULTS["gripper_tolerance"]


@settings(max_examples=40, deadline=None)
@given(start=st.floats(0.0, m.GRIPPER_OPEN), width=st.floats(0.02, 0.05))
def test_closing_on_a_block_stalls_only_once_the_fingers_stopped(start, width):
    """Never while the emulated fingers still move (also slowly, setting off or braking), and
    within the stall time and two polls of their stop."""
    block = KatanaModel().arm.gripper.encoder_for_width(width)
    if ENC.gripper_encoder_to_angle(block) >= start - 0.06:  # no room to close onto it
        return
    out, verdict_s, stopped_s = _run(start, m.GRIPPER_CLOSED, block)
    assert out.stalled and not out.reached_goal
    assert abs(out.position - ENC.gripper_encoder_to_angle(block)) < 1e-3
    period = 1.0 / DEFAULTS["poll_rate"]
    assert verdict_s - stopped_s >= DEFAULTS["gripper_stall_time"] - 1e-9
    assert verdict_s - stopped_s <= DEFAULTS["gripper_stall_time"] + 2 * period + 1e-9
