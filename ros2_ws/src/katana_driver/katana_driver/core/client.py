"""High-level calls to the Katana controller over one Transport (ROS-free)."""

from __future__ import annotations

from collections.abc import Sequence

from . import protocol as p
from .transport import Transport


class KatanaClient:
    """One method per controller command; replies decoded, refusals raised as ControllerError."""

    def __init__(self, transport: Transport) -> None:
        self.transport = transport
        #: commands that can move a motor (C, G, G+128, H) handed to the transport so far,
        #: counted before each is sent: a state read when this was unchanged since is current
        self.motion_commands = 0
        self.spline_commands = 0  # of which G, G+128 and H: what fills the move buffers

    def _call(self, command: p.Command) -> bytes:
        """An idempotent request: re-sent by the transport on a lost or corrupt reply."""
        return self.transport.request(command.payload, command.reply_len)

    def _once(self, command: p.Command) -> bytes | None:
        """A command that must not act twice: sent once (transport.NoReply: outcome unknown).
        Returns the reply payload, or None when a reply came but was unreadable. Only motion
        commands (G, G+128, H, some C) are sent this way."""
        self.motion_commands += 1
        return self.transport.command(command.payload, command.reply_len)

    def _motor(self, command: p.Command, once: bool = False) -> None:
        """A ``C`` command; its reply's success byte is checked (protocol.CommandFailed)."""
        if not once:
            self.motion_commands += 1
        reply = self._once(command) if once else self._call(command)
        p.check_motor_reply(reply, command.payload[1] & 0x7F)

    # ------------------------------------------------------------------ link
    def connect(self) -> None:
        self.transport.open()

    def close(self) -> None:
        self.transport.close()

    # ------------------------------------------------------------------ identification
    def echo(self) -> bool:
        return p.decode_echo(self._call(p.echo()))

    def master_version(self) -> tuple[int, int]:
        return p.decode_master_version(self._call(p.master_version()))

    def identification(self) -> str:
        return p.decode_identification(self._call(p.identification()))

    # ------------------------------------------------------------------ state
    def read_positions(self) -> list[int]:
        """Encoder positions of motors 1..6."""
        return p.decode_positions(self._call(p.read_positions()))

    def read_status(self) -> list[int]:
        """Status flags of motors 1..6 (protocol.STATUS_*)."""
        return p.decode_status(self._call(p.read_status()))

    def read_motor(self, motor: int) -> p.MotorState:
        return p.decode_motor(self._call(p.read_motor(motor)))

    def read_gripper_sensors(self) -> list[int]:
        return p.decode_gripper_sensors(self._call(p.gripper_sensors()))

    # ------------------------------------------------------------------ motor commands
    def move_motor(self, motor: int, encoder: int) -> None:
        """Sent once: a lost reply raises transport.NoReply (read the motor's state); a
        refusal raises ControllerError, a reply with success byte 0 CommandFailed."""
        self._motor(p.motor_command(motor, p.FLAG_MOVE, encoder), once=True)

    def hold_motor(self, motor: int, encoder: int) -> None:
        """Hold at ``encoder``; also clears a collision stop (as the vendor's unblock does)."""
        self._motor(p.motor_command(motor, p.FLAG_HOLD, encoder))

    def motor_off(self, motor: int) -> None:
        self._motor(p.motor_command(motor, p.FLAG_OFF))

    def motors_off(self) -> None:
        self._motor(p.motor_command(p.ALL_MOTORS, p.FLAG_OFF))

    def hold_all(self, encoders: Sequence[int]) -> None:
        """Every motor holds where ``encoders`` says (freeze: stop now)."""
        for motor, enc in enumerate(encoders, start=1):
            self.hold_motor(motor, int(enc))

    def calibrate(self) -> None:
        """Start calibrating all motors (sent once); poll read_status until none calibrates."""
        self._motor(p.calibrate_all(), once=True)

    def flush_buffers(self) -> None:
        self._motor(p.motor_command(p.ALL_MOTORS, p.FLAG_FLUSH))

    def set_encoder(self, motor: int, encoder: int) -> None:
        self._motor(p.motor_command(motor, p.FLAG_HOLD, encoder, set_encoder=True))

    def set_speed_limit(self, motor: int, positive: int, negative: int | None = None) -> None:
        """Speed limits in encoders per 10 ms (firmware maximum 180): ``S id 3 pos neg 0``."""
        neg = positive if negative is None else negative
        self._call(p.set_limit(motor, p.SUB_SPEED_LIMIT, positive, neg))

    def set_acceleration_limit(self, motor: int, acceleration: int) -> None:
        """Acceleration limit, encoders per (10 ms)^2 (ROS 1 node: 1 or 2): ``S id 4 a 0 0``."""
        self._call(p.set_limit(motor, p.SUB_ACCEL_LIMIT, acceleration))

    def collision_detection(self, on: bool) -> None:
        self._call(p.collision_detection(on))

    # ------------------------------------------------------------------ splines
    def send_spline(self, motor: int, segment: p.SplineSegment) -> None:
        """G: queue one motor's segment (sent once); start_splines runs what was queued."""
        self.spline_commands += 1
        self._once(p.spline_one(motor, segment))

    def start_splines(self, exact: bool = False, more: bool = False) -> None:
        self.spline_commands += 1
        self._once(p.start_splines(exact=exact, more=more))

    def send_spline_all(
        self, segments: Sequence[p.SplineSegment], activity: int, exact: bool = False
    ) -> None:
        """H: one segment for all six motors; ``activity`` is protocol.ACTIVITY_*. Sent once:
        a segment played twice would jump the arm (transport.NoReply: read the state)."""
        self.spline_commands += 1
        self._once(p.spline_all(list(segments), activity, exact))

    # ------------------------------------------------------------------ gripper
    def gripper(self, encoder: int) -> None:
        """Move the gripper motor (6) to ``encoder``."""
        self.move_motor(6, encoder)

    # ------------------------------------------------------------------ errors
    def read_last_error(self) -> p.ControllerError | None:
        """The controller's last error via the raw 0xC1 request (unconfirmed outside a 0xC0)."""
        err = self.transport.query_error()
        return err if isinstance(err, p.ControllerError) else None
