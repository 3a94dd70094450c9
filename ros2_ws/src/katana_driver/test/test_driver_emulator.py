"""Every command through the emulator over TCP and a pseudo-terminal; the error path; faults."""


import pytest
from katana_common.testing import wait_until
from katana_driver.core import protocol as p
from katana_driver.core.client import KatanaClient
from katana_driver.core.splines import hermite_segment, hold_segment
from katana_driver.core.transport import SerialTransport, TcpTransport, TransportError
from katana_emulator.arms import MODELS
from katana_emulator.emulator import BANNER, main

pytestmark = pytest.mark.timeout(60)


def tcp_client(emulator, timeout=0.3, retries=3):
    host, port = emulator.address
    client = KatanaClient(TcpTransport(host, port, timeout=timeout, retries=retries))
    client.connect()
    return client


def calibrated_client(make_emulator, **kwargs):
    emulator = make_emulator(**kwargs)
    client = tcp_client(emulator)
    client.calibrate()
    assert wait_until(lambda: all(s == p.STATUS_HOLDING for s in client.read_status()))
    return emulator, client


def test_identification_says_emulator(make_emulator):
    client = tcp_client(make_emulator())
    assert client.echo()
    # KNI drives a controller as a Katana 400/450 only when this is 3 or less (kmlBase.h:
    # K400_OLD_PROTOCOL_THRESHOLD 3, CKatBase::checkKatanaType)
    assert client.master_version()[0] <= 3
    assert BANNER in client.identification()


def test_uncalibrated_move_is_refused_with_the_controllers_message(make_emulator):
    client = tcp_client(make_emulator())
    with pytest.raises(p.ControllerError) as info:
        client.move_motor(1, 1000)
    assert info.value.message == "Axis not calibrated"
    assert info.value.axis == 1 and info.value.command == ord("C")
    assert client.echo()  # the link is fine afterwards
    assert client.read_last_error().message == "Axis not calibrated"


def test_calibration_runs_and_ends_at_the_stops(make_emulator):
    emulator = make_emulator(calibration_s=0.3)
    client = tcp_client(emulator)
    client.calibrate()
    assert client.read_status() == [p.STATUS_CALIBRATING] * 6
    assert wait_until(lambda: client.read_status() == [p.STATUS_HOLDING] * 6)
    assert client.read_positions() == list(MODELS[450].calibrated_encoders)


def test_motor_commands_round_trip(make_emulator):
    emulator, client = calibrated_client(make_emulator, time_scale=10.0)
    client.set_speed_limit(1, 150)
    client.set_acceleration_limit(1, 3)
    assert emulator.model.motors[0].speed_limit == 150
    client.move_motor(1, 25000)
    assert client.read_motor(1).status == p.STATUS_MOVING
    assert wait_until(lambda: client.read_motor(1).status == p.STATUS_HOLDING)
    state = client.read_motor(1)
    assert state.position == 25000 and state.velocity == 0
    client.hold_motor(2, -30000)
    assert wait_until(lambda: client.read_positions()[1] == -30000)
    client.set_encoder(4, 1234)
    assert client.read_positions()[3] == 1234
    client.motor_off(3)
    assert client.read_status()[2] == p.STATUS_OFF
    client.motors_off()
    assert client.read_status() == [p.STATUS_OFF] * 6
    client.collision_detection(True)
    assert emulator.model.collision_detection
    assert client.read_gripper_sensors() == [0] * 16


def test_spline_queue_g_and_h(make_emulator):
    emulator, client = calibrated_client(make_emulator, time_scale=10.0)
    start = client.read_positions()
    seg = hermite_segment(start[0], start[0] - 2000, 0.0, 0.0, 40)
    client.send_spline(1, seg)
    assert client.read_status()[0] == p.STATUS_HOLDING  # queued, not started
    client.start_splines()
    assert wait_until(lambda: client.read_status()[0] == p.STATUS_SPLINE_DONE)
    assert client.read_positions()[0] == start[0] - 2000

    now = client.read_positions()
    segs = [hold_segment(e, 30) for e in now]
    segs[1] = hermite_segment(now[1], now[1] + 3000, 0.0, 0.0, 30)
    client.send_spline_all(segs, p.ACTIVITY_QUEUE)
    assert client.read_status()[1] == p.STATUS_HOLDING
    segs2 = [hold_segment(e, 30) for e in client.read_positions()]
    segs2[1] = hold_segment(now[1] + 3000, 30)
    client.send_spline_all(segs2, p.ACTIVITY_LAST)
    assert wait_until(lambda: client.read_status()[1] == p.STATUS_SPLINE_DONE)
    assert client.read_positions()[1] == now[1] + 3000


def test_spline_refusals(make_emulator):
    emulator, client = calibrated_client(make_emulator)
    pos = client.read_positions()
    too_fast = p.SplineSegment(40, pos[0] - 8000, pos[0], -64 * 200, 0, 0)  # 200 enc/tick
    with pytest.raises(p.ControllerError, match="speed limit"):
        client.send_spline(1, too_fast)
    segs = [hold_segment(e, 30) for e in pos]
    for _ in range(16):
        client.send_spline_all(segs, p.ACTIVITY_QUEUE)
    with pytest.raises(p.ControllerError, match="Move buffer full"):
        client.send_spline_all(segs, p.ACTIVITY_QUEUE)
    client.flush_buffers()
    client.send_spline_all(segs, p.ACTIVITY_QUEUE)  # room again


def test_collision_injection_stops_everything_until_unblocked(make_emulator):
    emulator, client = calibrated_client(make_emulator)
    assert not emulator.model.inject_collision(2)  # detection off: nothing happens
    client.collision_detection(True)
    assert emulator.model.inject_collision(2)
    assert client.read_status() == [p.STATUS_COLLISION] * 6
    assert client.read_last_error().message == "Collision on axis 2"
    with pytest.raises(p.ControllerError, match="collision"):
        client.move_motor(1, 20000)
    client.hold_all(client.read_positions())
    assert client.read_status() == [p.STATUS_HOLDING] * 6


def test_unknown_command_is_refused(make_emulator):
    client = tcp_client(make_emulator())
    with pytest.raises(p.ControllerError, match="Unknown command"):
        client.transport.request(b"Q", 1)


def test_split_replies_are_reassembled(make_emulator):
    client = tcp_client(make_emulator(split_replies=True, split_delay_s=0.02))
    assert client.identification().startswith(BANNER)
    assert len(client.read_positions()) == 6
    assert client.transport.stats.retries == 0


def test_silent_replies_are_retried(make_emulator):
    emulator = make_emulator()
    client = tcp_client(emulator, timeout=0.1)
    emulator.faults.silent_next = 2
    assert client.read_positions() == emulator.model.encoders()
    assert client.transport.stats.retries >= 1 and client.transport.stats.timeouts >= 1


def test_corrupted_replies_are_retried(make_emulator):
    emulator = make_emulator()
    client = tcp_client(emulator, timeout=0.1)
    emulator.faults.corrupt_next = 1
    assert client.read_positions() == emulator.model.encoders()
    assert client.transport.stats.crc_errors == 1 and client.transport.stats.retries == 1


@pytest.mark.parametrize(("knob", "reason"), [("silent_next", "no reply"), ("corrupt_next", "CRC")])
def test_persistent_faults_end_in_a_clear_error(make_emulator, knob, reason):
    emulator = make_emulator()
    client = tcp_client(emulator, timeout=0.1, retries=3)
    setattr(emulator.faults, knob, 4)
    with pytest.raises(TransportError, match=f"after 4 attempts.*{reason}"):
        client.read_positions()
    assert client.read_positions()  # and the link still works once the fault is gone


def test_a_late_reply_is_not_taken_for_the_next_one(make_emulator):
    emulator = make_emulator()
    client = tcp_client(emulator, timeout=0.05)
    emulator.faults.latency_s = 0.08  # every reply comes after the client gave up once
    with pytest.raises(TransportError):
        client.read_status()
    emulator.faults.latency_s = 0.0
    assert client.read_positions() == emulator.model.encoders()


def test_serial_link_over_a_pseudo_terminal(make_emulator):
    emulator = make_emulator(serial=True)
    client = KatanaClient(SerialTransport(emulator.serial_device, timeout=0.3))
    client.connect()
    assert client.echo()
    assert client.read_positions() == emulator.model.encoders()
    with pytest.raises(p.ControllerError, match="Axis not calibrated"):
        client.move_motor(2, 0)
    emulator.faults.corrupt_next = 1
    assert client.read_status() == emulator.model.statuses()
    client.close()


def test_console_script_refuses_a_busy_port(make_emulator, capsys):
    emulator = make_emulator()
    assert main(["--port", str(emulator.address[1])]) == 1
    out = capsys.readouterr()
    assert BANNER in out.out and "cannot listen" in out.err


def test_a_segment_sent_twice_is_counted_and_shows_as_a_jump(make_emulator):
    """The fault counters can fail: a re-sent segment is a duplicate, and playing it again
    from its start position jumps the joint back, far above its speed limit."""
    emulator, client = calibrated_client(make_emulator)
    now = client.read_positions()
    speed = emulator.model.motors[0].nominal_speed  # encoders per tick
    ticks = 40
    segs = [hold_segment(e, ticks) for e in now]
    segs[0] = hermite_segment(now[0], now[0] - int(0.6 * speed * ticks), 0.0, 0.0, ticks)
    emulator.model.reset_counters()
    client.send_spline_all(segs, p.ACTIVITY_START)
    wait_until(lambda: client.read_status()[0] == p.STATUS_SPLINE_DONE)
    assert emulator.model.duplicated_segments == 0
    assert 0.8 < emulator.model.max_speed_ratio <= 1.0  # 0.6 x mean, x 1.5 at the peak
    client.send_spline_all(segs, p.ACTIVITY_START)  # the same segment again
    wait_until(lambda: client.read_status()[0] == p.STATUS_SPLINE_DONE)
    assert emulator.model.duplicated_segments == 1
    assert emulator.model.max_speed_ratio > 5.0
    client.flush_buffers()  # after a flush, the same row is a new command, not a duplicate
    client.send_spline_all([hold_segment(e, 20) for e in client.read_positions()],
                           p.ACTIVITY_LAST)
    assert emulator.model.duplicated_segments == 1


def test_a_failure_reply_to_c_raises_command_failed(make_emulator):
    """A C reply whose success byte (its second byte, KNI's `if (!buf[1]) throw`) is 0 raises
    CommandFailed, a ControllerError: whatever catches refusals catches it too."""
    emulator, client = calibrated_client(make_emulator)
    emulator.model.refuse_within, emulator.model.refuse_with_failure = 300, True
    with pytest.raises(p.CommandFailed, match="'C' for motor 1 with failure") as info:
        client.move_motor(1, 30900)  # 100 encoders from the end of motor 1's range
    assert isinstance(info.value, p.ControllerError)
    client.move_motor(1, 20000)  # far from the limits: taken
    assert client.read_status()[0] == p.STATUS_MOVING


def test_a_full_move_buffer_reports_152(make_emulator):
    """KNI's MSF_LINMOV, 152: "moving poly, polymb full"."""
    emulator, client = calibrated_client(make_emulator)
    emulator.model.queue_size = 2
    segs = [hold_segment(e, 50) for e in client.read_positions()]
    client.send_spline_all(segs, p.ACTIVITY_START)
    assert client.read_status()[0] == p.STATUS_MOVING
    client.send_spline_all(segs, p.ACTIVITY_START)
    assert client.read_status()[:5] == [152] * 5
    assert client.read_motor(1).status == 152
