"""Wire protocol: CRC, framing, test vectors of docs/KATANA.md, encoders and decoders."""

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_driver.core import protocol as p


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


@pytest.mark.parametrize(
    ("command", "frame"),
    [
        (p.echo(), "01 18 01 5A 3B 80"),
        (p.read_positions(), "01 18 03 4E 03 00 E7 60"),
        (p.read_motor(1), "01 18 02 44 01 C0 F2"),
        (p.calibrate_all(), "01 18 05 43 00 04 7D 00 5E 25"),
    ],
)
def test_request_vectors(command, frame):
    assert p.frame_request(command.payload) == bytes.fromhex(frame)


def test_echo_reply_vector():
    assert p.frame_reply(b"z") == bytes.fromhex("7A E3 81")
    assert p.decode_echo(p.check_reply(bytes.fromhex("7A E3 81"), 1))


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
def test_spline_all_round_trip(segs, activity, exact):
    decoded, act, ex = p.decode_spline_all(p.spline_all(segs, activity, exact).payload)
    assert decoded == segs and act == activity and ex == exact


@settings(deadline=None)  # no timed asserts: a loaded machine is not a bug
@given(st.integers(1, 6), segments)
def test_spline_one_round_trip_target_before_duration(motor, seg):
    payload = p.spline_one(motor, seg).payload
    assert int.from_bytes(payload[2:4], "big", signed=True) == seg.target
    assert int.from_bytes(payload[4:6], "big", signed=True) == seg.duration
    assert p.decode_spline_one(payload) == (motor, seg)


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
