"""Wire protocol: CRC, framing, golden frames of every command and reply (KNI 4.3.0's layouts),
encoders and decoders."""

from dataclasses import astuple

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_driver.core import protocol as p
from katana_emulator import wire


def crc16_arc_bitwise(data: bytes) -> int:
    """Reference CRC-16/ARC, bit by bit (independent of the library the driver uses)."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def test_crc_check_value():
    assert p.crc16_arc(b"123456789") == 0xBB3D
    assert crc16_arc_bitwise(b"123456789") == 0xBB3D


@settings(deadline=None)  # no timed asserts: a loaded machine is not a bug
@given(st.binary(max_size=300))
def test_crc_matches_bitwise_reference(data):
    assert p.crc16_arc(data) == crc16_arc_bitwise(data)


SEG = p.SplineSegment(duration=50, target=-1000, p0=-1000, p1=256, p2=-128, p3=64)
# one motor's segment on the wire (signed 16-bit, high byte first): duration 50 = 00 32,
# target -1000 = FC 18, p0 -1000 = FC 18, p1 256 = 01 00, p2 -128 = FF 80, p3 64 = 00 40
SEG_H = "00 32 FC 18 FC 18 01 00 FF 80 00 40"


# Every request the driver sends, as whole frames: 01 (header), 18 (address 24), the payload
# length, the payload as KNI 4.3.0 lays it out (the function named), the CRC-16/ARC of the
# payload high byte first. The payload bytes are written out by hand from those facts, and the
# CRC is checked again with the bitwise reference above: nothing here is the driver's output.
REQUEST_FRAMES = [
    # CKatBase::recvECH: 'Z'
    (p.echo(), "01 18 01 5A 3B 80"),
    # CKatBase::recvMFW: 'B'
    (p.master_version(), "01 18 01 42 31 80"),
    # CKatBase::recvIDS: 'Y'
    (p.identification(), "01 18 01 59 3A C0"),
    # CKatBase::recvMPS: 'N' 3 0
    (p.read_positions(), "01 18 03 4E 03 00 E7 60"),
    # CKatBase::recvGMS: 'N' 1 0
    (p.read_status(), "01 18 03 4E 01 00 87 61"),
    # CMotBase::recvPVP: 'D' id
    (p.read_motor(1), "01 18 02 44 01 C0 F2"),
    (p.read_motor(6), "01 18 02 44 06 02 B3"),
    # CMotBase::sendTPS: 'C' id flag target_hi target_lo; move (24) motor 3 to -2 = FF FE
    (p.motor_command(3, p.FLAG_MOVE, -2), "01 18 05 43 03 18 FF FE FC 05"),
    # freeze/hold (8) motor 2 at 1234 = 04 D2 (CMotBase::resetBlocked sends the same shape)
    (p.motor_command(2, p.FLAG_HOLD, 1234), "01 18 05 43 02 08 04 D2 28 47"),
    # off (0): motor 5, and all motors (id 0)
    (p.motor_command(5, p.FLAG_OFF), "01 18 05 43 05 00 00 00 03 45"),
    (p.motor_command(0, p.FLAG_OFF), "01 18 05 43 00 00 00 00 CF 45"),
    # the gripper (motor 6) to 30766 = 78 2E
    (p.motor_command(6, p.FLAG_MOVE, 30766), "01 18 05 43 06 18 78 2E 5C 67"),
    # calibrate all: 'C' 0 4 32000 (7D 00)
    (p.calibrate_all(), "01 18 05 43 00 04 7D 00 5E 25"),
    # CKatBase::flushMoveBuffers: 'C' 0 32 0 0
    (p.motor_command(0, p.FLAG_FLUSH), "01 18 05 43 00 20 00 00 05 44"),
    # CMotBase::sendAPS: 'C' id+128 flag encoder; motor 2 (82) set to 31000 = 79 18
    (p.motor_command(2, p.FLAG_HOLD, 31000, set_encoder=True),
     "01 18 05 43 82 08 79 18 EF CF"),
    # CMotBase::setSpeedLimits: 'S' id 3 positive negative 0 (180 = B4)
    (p.set_limit(2, p.SUB_SPEED_LIMIT, 180, 180), "01 18 06 53 02 03 B4 B4 00 C1 42"),
    # CMotBase::setAccelerationLimit: 'S' id 4 acceleration 0 0
    (p.set_limit(6, p.SUB_ACCEL_LIMIT, 2), "01 18 06 53 06 04 02 00 00 93 24"),
    # CMotBase::sendSpline: 'G' id target duration p1 p2 p3 p4 (KNI's p1..p4: p0..p3 here)
    (p.spline_one(1, SEG), "01 18 0E 47 01 FC 18 00 32 FC 18 01 00 FF 80 00 40 DB 83"),
    # CKatBase::startSplineMovement(exactflag, moreflag): 'G'+128 (C7) moreflag exactflag
    (p.start_splines(exact=True, more=False), "01 18 03 C7 00 01 3D 70"),
    (p.start_splines(exact=False, more=True), "01 18 03 C7 01 00 6D B0"),
    # CKatBase::setAndStartPolyMovement: 'H', 36 shorts (six motors), moreflag, exactflag
    (p.spline_all([SEG] * 6, p.ACTIVITY_LAST, exact=True),
     "01 18 4B 48 " + " ".join([SEG_H] * 6) + " 01 01 0B B6"),
    # CKatBase::enableCrashLimits on a 400/450 (all motors, 0): 'A' 0 1; disable: 'A' 0 0
    (p.collision_detection(True), "01 18 03 41 00 01 D4 91"),
    (p.collision_detection(False), "01 18 03 41 00 00 14 50"),
    # the gripper's sensor controller, id 15: 'E' 15
    (p.gripper_sensors(), "01 18 02 45 0F 94 72"),
]


@pytest.mark.parametrize(("command", "frame"), REQUEST_FRAMES)
def test_request_frames_are_knis(command, frame):
    data = bytes.fromhex(frame)
    assert p.frame_request(command.payload) == data
    assert crc16_arc_bitwise(data[3:-2]).to_bytes(2, "big") == data[-2:]
    assert p.parse_request(data) == command.payload  # the emulator's side reads it back


def test_every_command_has_a_golden_frame():
    """Each command letter the driver sends appears in REQUEST_FRAMES, and each C flag."""
    letters = {cmd.letter for cmd, _ in REQUEST_FRAMES}
    assert letters == set(p.REQUEST_LENGTHS)
    flags = {cmd.payload[2] for cmd, _ in REQUEST_FRAMES if cmd.letter == ord("C")}
    assert flags == {p.FLAG_OFF, p.FLAG_CALIBRATE, p.FLAG_HOLD, p.FLAG_MOVE, p.FLAG_FLUSH}


def test_the_error_query_is_sent_raw():
    """After a C0 reply the client sends 00 00 00 C1: no header, no length, no CRC."""
    assert p.ERROR_QUERY == bytes.fromhex("00 00 00 C1")


def _reply(frame: str, command: p.Command) -> bytes:
    data = bytes.fromhex(frame)
    assert crc16_arc_bitwise(data[:-2]).to_bytes(2, "big") == data[-2:]
    return p.check_reply(data, command.reply_len)


def test_echo_reply_vector():
    assert p.frame_reply(b"z") == bytes.fromhex("7A E3 81")
    assert p.decode_echo(_reply("7A E3 81", p.echo()))
    assert not p.decode_echo(_reply("5A 3B 80", p.echo()))  # 'Z' back is not the echo


def test_master_version_reply():
    """CKatBase::recvMFW: version buf[1], revision buf[2]."""
    assert p.decode_master_version(_reply("62 03 01 EE 60", p.master_version())) == (3, 1)


def test_identification_reply():
    """CKatBase::recvIDS: the text from buf[1], NUL-terminated."""
    payload = b"y" + b"Katana 450".ljust(83, b"\x00")
    frame = (payload + bytes.fromhex("B1 0B")).hex(" ")
    assert p.decode_identification(_reply(frame, p.identification())) == "Katana 450"


def test_positions_reply():
    """CKatBase::recvMPS: motor i's position is (buf[2i+1] << 8) | buf[2i+2], signed."""
    frame = "6E 79 18 86 E8 9C 37 00 00 FF FF 4E 20 B8 86"
    assert p.decode_positions(_reply(frame, p.read_positions())) == [
        31000, -31000, -25545, 0, -1, 20000]


def test_status_reply():
    """CKatBase::recvGMS: motor i's status flag is buf[i+1]."""
    frame = "6E 08 18 10 98 28 58 00 00 00 00 00 00 79 18"
    assert p.decode_status(_reply(frame, p.read_status())) == [8, 24, 16, 152, 40, 88]


def test_motor_reply():
    """CMotBase::recvPVP: status buf[2], position buf[3..4], velocity buf[5..6] (signed),
    pwm buf[7] (unsigned)."""
    state = p.decode_motor(_reply("64 01 18 FF 38 FF F6 C8 B1 7B", p.read_motor(1)))
    assert (state.status, state.position, state.velocity, state.pwm) == (24, -200, -10, 200)


def test_motor_command_replies():
    """CMotBase::sendTPS: success byte buf[1]; 0 is a failure."""
    cmd = p.motor_command(3, p.FLAG_MOVE, -2)
    p.check_motor_reply(_reply("63 01 03 8F B1", cmd), 3)
    with pytest.raises(p.CommandFailed):
        p.check_motor_reply(_reply("63 00 03 1F B0", cmd), 3)


def test_gripper_sensor_reply():
    """The sensor controller's 16 values from buf[2]."""
    frame = "65 0F " + " ".join(f"{i:02X}" for i in range(16)) + " 37 31"
    assert p.decode_gripper_sensors(_reply(frame, p.gripper_sensors())) == list(range(16))


@pytest.mark.parametrize(
    ("command", "frame"),
    [
        (p.set_limit(2, p.SUB_SPEED_LIMIT, 180, 180), "73 02 03 B4 B4 00 A1 45"),
        (p.spline_one(1, SEG), "67 01 F0 EB"),
        (p.start_splines(), "C7 01 F0 93"),
        (p.spline_all([SEG] * 6, p.ACTIVITY_LAST), "68 01 01 8C 41"),
        (p.collision_detection(True), "61 01 50 E8"),
    ],
)
def test_replies_read_for_their_length_only(command, frame):
    """The driver reads these replies whole (length and CRC) and uses nothing in them."""
    assert _reply(frame, command) == bytes.fromhex(frame)[:-2]


def test_error_reply_frame():
    """C1, the refused command, the signed code, the axis, 51 message bytes, the CRC."""
    payload = bytes((0xC1, ord("C"), 0xFD, 2)) + b"Axis not calibrated".ljust(51, b"\x00")
    err = p.decode_error_reply(payload + bytes.fromhex("62 9E"))
    assert (err.command, err.code, err.axis, err.message) == (
        ord("C"), -3, 2, "Axis not calibrated")


@pytest.mark.parametrize(
    ("command", "request_len", "reply_len"),
    [
        (p.echo(), 1, 1),
        (p.master_version(), 1, 3),
        (p.identification(), 1, 84),
        (p.read_positions(), 3, 13),
        (p.read_status(), 3, 13),
        (p.read_motor(3), 2, 8),
        (p.motor_command(2, p.FLAG_MOVE, -1234), 5, 3),
        (p.set_limit(1, p.SUB_SPEED_LIMIT, 100, 100), 6, 6),
        (p.spline_one(1, p.SplineSegment(50, 10, 0, 1, 2, 3)), 14, 2),
        (p.start_splines(), 3, 2),
        (p.spline_all([p.SplineSegment(50, 1, 0, 0, 0, 0)] * 6, p.ACTIVITY_LAST), 75, 3),
        (p.collision_detection(True), 3, 2),
        (p.gripper_sensors(), 2, 18),
    ],
)
def test_command_sizes_follow_the_table(command, request_len, reply_len):
    assert len(command.payload) == request_len
    assert command.reply_len == reply_len
    assert p.REQUEST_LENGTHS[command.letter] == request_len


@settings(deadline=None)  # no timed asserts: a loaded machine is not a bug
@given(st.binary(min_size=1, max_size=255))
def test_request_framing_round_trip(payload):
    assert p.parse_request(p.frame_request(payload)) == payload


@settings(deadline=None)  # no timed asserts: a loaded machine is not a bug
@given(st.binary(min_size=1, max_size=80), st.data())
def test_single_bit_errors_are_detected(payload, data):
    frame = bytearray(p.frame_reply(payload))
    bit = data.draw(st.integers(0, len(frame) * 8 - 1))
    frame[bit // 8] ^= 1 << (bit % 8)
    with pytest.raises(p.CrcError):
        p.check_reply(bytes(frame), len(payload))


def test_wrong_reply_length_is_a_protocol_error():
    with pytest.raises(p.ProtocolError):
        p.check_reply(p.frame_reply(b"abc"), 4)


@settings(deadline=None)  # no timed asserts: a loaded machine is not a bug
@given(
    st.integers(0, 255),
    st.integers(-128, 127),
    st.integers(0, 6),
    st.text(alphabet=st.characters(min_codepoint=32, max_codepoint=126), max_size=50),
)
def test_error_reply_round_trip(command, code, axis, message):
    data = p.encode_error_reply(command, code, axis, message)
    assert len(data) == p.ERROR_REPLY_LEN
    err = p.decode_error_reply(data)
    assert (err.command, err.code, err.axis, err.message) == (command, code, axis, message)


def test_error_reply_layout_by_hand():
    payload = bytes((0xC1, ord("C"), 0xFD, 2)) + b"Axis not calibrated".ljust(51, b"\x00")
    data = payload + p.crc16_arc(payload).to_bytes(2, "big")
    err = p.decode_error_reply(data)
    assert err.code == -3 and err.axis == 2 and err.message == "Axis not calibrated"
    assert "Axis not calibrated" in str(err) and "'C'" in str(err)


int16 = st.integers(p.INT16_MIN, p.INT16_MAX)
segments = st.builds(p.SplineSegment, st.integers(1, 32767), int16, int16, int16, int16, int16)


@settings(deadline=None)  # no timed asserts: a loaded machine is not a bug
@given(st.lists(segments, min_size=6, max_size=6), st.sampled_from([0, 1, 2]), st.booleans())
def test_spline_all_reads_back_with_the_emulators_reader(segs, activity, exact):
    """The emulator's own reader (katana_emulator.wire, no code shared) gets the segments."""
    payload = p.spline_all(segs, activity, exact).payload
    decoded, act = wire.read_h(payload)
    assert [s.fields() for s in decoded] == [astuple(s) for s in segs]
    assert act == activity and payload[74] == int(exact)


@settings(deadline=None)  # no timed asserts: a loaded machine is not a bug
@given(st.integers(1, 6), segments)
def test_spline_one_round_trip_target_before_duration(motor, seg):
    payload = p.spline_one(motor, seg).payload
    assert int.from_bytes(payload[2:4], "big", signed=True) == seg.target
    assert int.from_bytes(payload[4:6], "big", signed=True) == seg.duration
    motor_read, read = wire.read_g(payload)
    assert (motor_read, read.fields()) == (motor, astuple(seg))


@settings(deadline=None)  # no timed asserts: a loaded machine is not a bug
@given(st.lists(int16, min_size=6, max_size=6))
def test_positions_decoder(values):
    payload = b"n" + b"".join(v.to_bytes(2, "big", signed=True) for v in values)
    assert p.decode_positions(payload) == values


def test_motor_command_encoding():
    assert p.motor_command(3, p.FLAG_MOVE, -2).payload == bytes((0x43, 3, 24, 0xFF, 0xFE))
    assert p.motor_command(2, p.FLAG_HOLD, 5, set_encoder=True).payload[1] == 130


@pytest.mark.parametrize(
    "make",
    [
        lambda: p.motor_command(7, p.FLAG_MOVE, 0),
        lambda: p.motor_command(1, p.FLAG_MOVE, 40000),
        lambda: p.read_motor(0),
        lambda: p.set_limit(1, p.SUB_SPEED_LIMIT, 300),
        lambda: p.spline_all([p.SplineSegment(1, 0, 0, 0, 0, 0)] * 5, 0),
    ],
)
def test_invalid_arguments_are_refused(make):
    with pytest.raises(ValueError):
        make()


def test_moving_statuses_are_knis():
    """KNI 4.3.0's TMotStsFlg (kmlMotBase.h): MSF_NORMOPSTAT = 16 "moving (polymb not full)",
    MSF_LINMOV = 152 "moving poly, polymb full"; 24 the Katana4D manual's moving state."""
    assert p.MOVING_STATUSES == {16, 24, 152}
    assert (p.STATUS_FOLLOWING, p.STATUS_MOVING, p.STATUS_BUFFER_FULL) == (16, 24, 152)
    assert not p.MOVING_STATUSES & {0, 4, 8, 40, 88, 128}


def test_limit_frames_follow_kni():
    """CMotBase::setSpeedLimits sends 'S', id, 3, positive, negative, 0 and
    setAccelerationLimit 'S', id, 4, acceleration, 0, 0 (KNI 4.3.0 kmlMotBase.cpp); the ROS 1
    node sends 180 and 2 to every motor (katana_constants.h)."""
    assert p.set_limit(2, p.SUB_SPEED_LIMIT, 180, 180).payload == bytes((0x53, 2, 3, 180, 180, 0))
    assert p.set_limit(6, p.SUB_ACCEL_LIMIT, 2).payload == bytes((0x53, 6, 4, 2, 0, 0))
    assert (p.KNI_MAX_VELOCITY, p.KNI_MAX_ACCELERATION) == (180, 2)


def test_pwm_is_decoded_unsigned_as_kni_reads_it():
    """CMotBase::recvPVP: pvp.pwm = buf[7], a `byte` (unsigned char); pos and vel signed."""
    state = p.decode_motor(bytes.fromhex("64 01 18 FF 38 FF F6 C8"))
    assert (state.status, state.position, state.velocity, state.pwm) == (24, -200, -10, 200)


def test_a_c_reply_with_success_byte_0_is_a_failure():
    """CMotBase::sendTPS: `if (!buf[1]) throw ParameterWritingException("TPS")`."""
    p.check_motor_reply(b"c\x01\x03", 3)
    p.check_motor_reply(None, 3)  # came but unreadable: cannot say
    with pytest.raises(p.CommandFailed, match="motor 3") as info:
        p.check_motor_reply(b"c\x00\x03", 3)
    assert isinstance(info.value, p.ControllerError)
