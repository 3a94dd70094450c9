"""The arm worker against the emulator: calibration, trajectories, faults, lost links."""

import threading

import pytest
from katana_driver.core import motion
from katana_driver.core import protocol as p
from katana_driver.core.arm import ArmWorker
from katana_driver.core.encoders import EncoderModel
from katana_driver.core.splines import hold_segment, plan_trajectory
from katana_driver.core.transport import TcpTransport
from katana_emulator.arms import MODELS

pytestmark = pytest.mark.timeout(60)
MODEL = EncoderModel()


class Worker:
    """An ArmWorker with a log and a state counter, stopped at the end of the test."""

    def __init__(self, emulator, **kwargs):
        self.logs: list[tuple[str, str]] = []
        self.states = 0
        self.changed = threading.Event()
        host, port = emulator.address
        kwargs.setdefault("reconnect_period", 0.2)
        model = kwargs.pop("model", MODEL)
        self.worker = ArmWorker(
            TcpTransport(host, port, timeout=0.2),
            model,
            on_state=self._on_state,
            log=lambda level, text: self.logs.append((level, text)),
            **kwargs,
        )
        self.worker.start()

    def _on_state(self, state):
        self.states += 1

    def wait(self, predicate, polls=150):
        """Wait for ``predicate`` over a bounded number of polls (each at most 0.2 s)."""
        last = 0.0
        for _ in range(polls):
            if predicate():
                return True
            state = self.worker.wait_state(after=last, timeout=0.2)
            if state is not None:
                last = state.stamp
        return predicate()


@pytest.fixture
def worker_for():
    made = []

    def make(emulator, **kwargs):
        w = Worker(emulator, **kwargs)
        made.append(w)
        return w

    yield make
    for w in made:
        w.worker.stop()


@pytest.mark.parametrize("variant", ["6M180", "6M90A", "6M90B"])
def test_calibrates_when_needed_and_ends_inside_the_limits(make_emulator, worker_for, variant):
    """After the calibration run (every motor on its stop, KNI's encoder offsets +-31000) the
    arm backs off its stops by at least 200 encoders (the margin a real controller is reported
    to refuse), not the 75-151 of a 0.01 rad back-off, so the pose it reports lies inside the
    joint limits by that margin: at the stop itself the converted angle fell 3e-7 rad outside
    the rounded limits and every IK or goal check refused to start."""
    model = EncoderModel(variant)
    emulator = make_emulator(variant=variant)
    w = worker_for(emulator, model=model)
    assert w.wait(lambda: w.worker.ready)
    kni_stops = [31000, -31000, -31000, 31000, 31000]  # KNI cfg encoderOffset, motors 1..5
    # where the emulator's calibration ends
    assert list(MODELS[450].calibrated_encoders[:5]) == kni_stops

    def backed_off():
        encoders = w.worker.state.encoders[:5]
        return all(200 <= abs(e - stop) <= 200 + 20
                   for e, stop in zip(encoders, kni_stops, strict=True))

    assert w.wait(backed_off)
    positions = w.worker.state.positions
    for motor in range(1, 6):
        lower, upper = model.joint_limits(motor)
        margin = 200 / abs(model.params(motor).enc_per_rad)
        assert lower + margin <= positions[motor - 1] <= upper - margin
    assert emulator.model.calibrations == 1
    assert positions[5] == pytest.approx(0.30, abs=1e-3)  # gripper open, not past it
    texts = " ".join(t for _, t in w.logs)
    assert "Axis not calibrated" in texts and "calibration done" in texts
    assert "master firmware version 3.0" in texts
    assert any(level == "warn" and "emulator" in t for level, t in w.logs)


def test_without_calibration_the_arm_is_reported_uncalibrated(make_emulator, worker_for):
    w = worker_for(make_emulator(), calibrate_on_start=False)
    assert w.wait(lambda: w.worker.connected and w.worker.state is not None)
    assert not w.worker.calibrated
    assert any("not calibrated" in t for level, t in w.logs if level == "error")


def test_follows_a_trajectory_within_tolerance(make_emulator, worker_for):
    emulator = make_emulator()
    w = worker_for(emulator)
    assert w.wait(lambda: w.worker.ready)
    times = [1.6, 3.2]
    goals = [[-2.7, 1.9, -1.9, -1.7, -2.6], [-2.4, 1.7, -1.6, -1.4, -2.3]]
    plan = plan_trajectory(MODEL, w.worker.state.encoders, times, goals)
    with w.worker.busy():
        stream = w.worker.start_trajectory(plan)
        t0 = stream.started.result(timeout=5)
        worst = 0.0
        done = False
        last = t0
        for _ in range(200):
            state = w.worker.wait_state(after=last, timeout=1.0)
            assert state is not None
            last = state.stamp
            # the controller's schedule, as the driver judges it (motion._judge): a segment
            # that went in late (a loaded machine) shifts everything after it by stream.lag_s
            desired = plan.desired_at(max(0.0, state.stamp - t0 - stream.lag_s))
            worst = max(
                worst, max(abs(a - d) for a, d in zip(state.positions[:5], desired, strict=True))
            )
            end = t0 + stream.lag_s + plan.duration_s
            if state.status_stamp > end and all(s == p.STATUS_SPLINE_DONE
                                                for s in state.status[:5]):
                done = True
                break
    assert done
    assert worst < 0.05  # rad: timing offsets of a poll, at speeds under 1 rad/s
    assert w.worker.state.positions[:5] == pytest.approx(goals[-1], abs=2e-3)
    assert emulator.model.statuses()[5] == p.STATUS_SPLINE_DONE  # the gripper held its place
    # what the emulated motors played kept to KNI's acceleration limit, 2 encoders per tick^2
    # (the ROS 1 node's KNI_MAX_ACCELERATION), give or take the rounding of p2 and p3
    assert 0.5 < emulator.model.max_spline_accel <= 2.0 + 0.1, emulator.model.max_spline_accel


def test_long_trajectories_are_streamed_through_the_move_buffer(make_emulator, worker_for):
    emulator = make_emulator(time_scale=1.0)
    w = worker_for(emulator)
    assert w.wait(lambda: w.worker.ready)
    # 12 s of pan motion in 0.5 s segments: 24 segments, more than the 16-slot buffer.
    times = [2.0 * (k + 1) for k in range(6)]
    goals = [[-3.0 + 0.15 * (k + 1), 2.1, -2.15, -1.95, -2.9] for k in range(6)]
    plan = plan_trajectory(MODEL, w.worker.state.encoders, times, goals)
    assert len(plan.segments) > 16
    emulator.model.time_scale = 1.0
    with w.worker.busy():
        stream = w.worker.start_trajectory(plan)
        stream.started.result(timeout=5)
        stream.finished_sending.result(timeout=20)
    assert w.wait(lambda: w.worker.state.status[0] == p.STATUS_SPLINE_DONE, polls=200)
    assert w.worker.state.positions[0] == pytest.approx(goals[-1][0], abs=2e-3)


def test_reconnects_after_a_lost_link(make_emulator, worker_for):
    emulator = make_emulator(calibrated=True)
    w = worker_for(emulator)
    assert w.wait(lambda: w.worker.connected)
    emulator.drop_connection()
    assert w.wait(lambda: any("lost connection" in t for _, t in w.logs))
    assert w.wait(lambda: w.worker.connected)
    before = w.states
    assert w.wait(lambda: w.states > before + 3)


def test_collision_is_reported_with_the_controllers_message(make_emulator, worker_for):
    emulator = make_emulator(calibrated=True)
    w = worker_for(emulator)
    assert w.wait(lambda: w.worker.connected and emulator.model.collision_detection)
    assert emulator.model.inject_collision(3)
    assert w.wait(lambda: bool(w.worker.collision_message))
    assert "Collision on axis 3" in w.worker.collision_message


def test_survives_split_and_occasional_bad_replies(make_emulator, worker_for):
    emulator = make_emulator(calibrated=True, split_replies=True, corrupt_rate=0.05, seed=3)
    w = worker_for(emulator)
    assert w.wait(lambda: w.worker.connected)
    assert w.wait(lambda: w.states > 30)
    assert w.worker.transport.stats.crc_errors > 0
    assert w.worker.state.encoders == emulator.model.encoders()


def test_jobs_fail_fast_when_not_connected(make_emulator, worker_for):
    emulator = make_emulator()
    emulator.stop()  # nobody listens
    w = worker_for(emulator)
    future = w.worker.submit(lambda client: client.echo())
    with pytest.raises(Exception, match="no connection"):
        future.result(timeout=1)


def test_a_refused_segment_ends_the_stream_not_the_worker(make_emulator, worker_for):
    """The collision test's flake: a collision stopped the arm between two polls, the next
    spline segment was refused (0xC0), and the ControllerError ended the worker thread, so no
    joint state came any more. Here the controller refuses the second segment for certain."""
    emulator = make_emulator(calibrated=True)
    w = worker_for(emulator)
    assert w.wait(lambda: w.worker.ready)
    client = w.worker.client
    real_send, calls = client.send_spline_all, []

    def send(segments, activity, exact=False):
        calls.append(activity)
        if len(calls) == 2:
            emulator.model.collision_detection = True
            emulator.model.inject_collision(2)  # the next H is refused: axis stopped
        return real_send(segments, activity, exact)

    client.send_spline_all = send
    state = w.worker.state
    plan = plan_trajectory(MODEL, state.encoders, [3.0], [[-1.5, 1.2, -1.0, -0.5, -1.5]])
    assert len(plan.segments) > 3
    stream = w.worker.start_trajectory(plan)
    with pytest.raises(RuntimeError, match="collision"):
        stream.finished_sending.result(timeout=10)
    polls = w.worker.polls
    assert w.wait(lambda: w.worker.polls > polls + 5)  # the worker still polls
    assert w.worker._thread.is_alive()


def test_start_up_sends_knis_speed_and_acceleration_limits(make_emulator, worker_for):
    """Every motor gets the limits the ROS 1 node sets at start-up through KNI: speed 180
    encoders per 10 ms (KNI_MAX_VELOCITY) and acceleration 2 per (10 ms)^2
    (KNI_MAX_ACCELERATION), whatever the controller held before."""
    emulator = make_emulator(calibrated=True)
    for m in emulator.model.motors:
        m.speed_limit, m.accel_limit = 50.0, 4.0
    w = worker_for(emulator)
    assert w.wait(lambda: w.worker.ready)
    assert [m.speed_limit for m in emulator.model.motors] == [180] * 6
    assert [m.accel_limit for m in emulator.model.motors] == [2] * 6


def test_a_reconnection_does_not_calibrate_a_calibrated_arm(make_emulator, worker_for):
    """The controller keeps its calibration while it stays powered: neither a lost link nor a
    driver restart calibrates it again. Not even after a collision, whose stopped motors refuse
    moves as an uncalibrated arm does: the probe held them first (once it took the collision
    for a lost calibration, and the arm stayed "not calibrated" until a restart recalibrated)."""
    emulator = make_emulator()  # uncalibrated: the first connection calibrates it
    w = worker_for(emulator)
    assert w.wait(lambda: w.worker.ready)
    assert emulator.model.calibrations == 1
    assert emulator.model.inject_collision(2)  # set-up turned collision detection on
    assert w.wait(lambda: bool(w.worker.collision_message))
    emulator.drop_connection()
    assert w.wait(lambda: w.worker.link_losses == 1)
    assert w.wait(lambda: w.worker.ready)
    assert w.worker.calibrated and emulator.model.calibrations == 1
    w.worker.stop()
    emulator.model.inject_collision(3)
    again = worker_for(emulator)  # a driver restart: a new worker, the same powered controller
    assert again.wait(lambda: again.worker.ready)
    assert emulator.model.calibrations == 1
    assert not any("calibrat" in t for _, t in again.logs)


@pytest.mark.parametrize("failure", [False, True], ids=["refused", "failure_reply"])
def test_a_refused_back_off_ends_set_up_with_the_arm_frozen(make_emulator, worker_for, failure):
    """A controller that refuses targets within 300 encoders of its limits refuses the back-off
    after calibration (0xC0, or a C reply with success byte 0): set-up ends, the arm holds
    where it is, goals are refused with the reason, and the worker keeps polling."""
    emulator = make_emulator()
    emulator.model.refuse_within, emulator.model.refuse_with_failure = 300, failure
    w = worker_for(emulator)
    assert w.wait(lambda: bool(w.worker.setup_problem) and w.worker.connected)
    problem = w.worker.setup_problem
    assert problem.startswith("set-up stopped: controller ")
    assert ("success byte 0" if failure else "Target too close to the limit") in problem
    assert not w.worker.ready and motion.ready_problem(w.worker) == problem
    assert w.wait(lambda: [m.status for m in emulator.model.motors] == [p.STATUS_HOLDING] * 6)
    polls = w.worker.polls
    assert w.wait(lambda: w.worker.polls > polls + 5)
    assert w.worker._thread.is_alive()
    assert any(level == "error" and "set-up stopped" in t for level, t in w.logs)


def test_a_controller_kni_refuses_as_a_450_gets_no_command(make_emulator, worker_for):
    """KNI exits when a controller configured as a 400/450 answers B with a version above 3
    (CKatBase::checkKatanaType, "Incompatible Config File"): the driver sends it nothing
    (no limits, no calibration), refuses goals with the reason, and keeps reading its state."""
    emulator = make_emulator()
    emulator.model.master_version = (4, 0)
    speed_limits = [m.speed_limit for m in emulator.model.motors]
    w = worker_for(emulator)
    assert w.wait(lambda: bool(w.worker.setup_problem) and w.worker.connected)
    assert "master version 4 is above 3" in w.worker.setup_problem
    polls = w.worker.polls
    assert w.wait(lambda: w.worker.polls > polls + 5)
    assert not w.worker.ready and motion.ready_problem(w.worker) == w.worker.setup_problem
    assert emulator.model.calibrations == 0
    assert [m.speed_limit for m in emulator.model.motors] == speed_limits
    assert [m.status for m in emulator.model.motors] == [p.STATUS_OFF] * 6
    assert any(level == "error" and "set-up refused" in t for level, t in w.logs)


def _play_to_the_end(w, emulator, plan, goal, timeout_s: float) -> None:
    """Send every segment of `plan`; the arm ends at `goal`, no segment taken twice."""
    with w.worker.busy():
        stream = w.worker.start_trajectory(plan)
        stream.finished_sending.result(timeout=timeout_s)
    assert w.wait(lambda: w.worker.state.positions[:5] == pytest.approx(goal, abs=2e-3))
    assert emulator.model.duplicated_segments == 0


def test_a_lost_segment_reply_counts_as_taken_while_the_motors_report_16(make_emulator,
                                                                         worker_for):
    """KNI's MSF_NORMOPSTAT, 16, is "moving (polymb not full)": a controller reporting it for
    moving motors, when a segment's reply is lost, says the segment plays (once only 24 counted:
    the segment was taken for lost and the trajectory aborted)."""
    emulator = make_emulator(calibrated=True)
    w = worker_for(emulator)
    assert w.wait(lambda: w.worker.ready)
    emulator.model.moving_status = 16
    client = w.worker.client
    real_send, calls = client.send_spline_all, []

    def send(segments, activity, exact=False):
        calls.append(activity)
        if len(calls) == 3:
            emulator.faults.silent_next = 1  # the controller takes it; its reply is lost
        return real_send(segments, activity, exact)

    client.send_spline_all = send
    goal = [-1.5, 1.2, -1.0, -0.5, -1.5]
    plan = plan_trajectory(MODEL, w.worker.state.encoders, [3.0], [goal])
    _play_to_the_end(w, emulator, plan, goal, timeout_s=15)
    assert any("segment 2 was taken" in t for _, t in w.logs)


def test_a_full_move_buffer_is_waited_out_before_the_next_segment(make_emulator, worker_for):
    """KNI waits while a motor reports 152 ("moving poly, polymb full") before it sends a
    segment; so does the driver: a controller whose buffer holds two segments plays a
    12-segment trajectory to its end, without a refused ("Move buffer full") segment."""
    emulator = make_emulator(calibrated=True)
    w = worker_for(emulator)
    assert w.wait(lambda: w.worker.ready)
    emulator.model.queue_size = 2
    goal = [-2.0, 1.5, -1.5, -1.0, -2.0]
    plan = plan_trajectory(MODEL, w.worker.state.encoders, [6.0], [goal])
    assert len(plan.segments) == 12
    _play_to_the_end(w, emulator, plan, goal, timeout_s=20)
    assert any("move buffer is full (152): waiting" in t for _, t in w.logs)


def test_an_unknown_status_is_logged_once(make_emulator, worker_for):
    """A status value outside KNI's TMotStsFlg (and 24) is reported, once, for the checklist."""
    emulator = make_emulator(calibrated=True)
    w = worker_for(emulator)
    assert w.wait(lambda: w.worker.ready)
    emulator.model.status_override = {2: 99}
    polls = w.worker.polls
    assert w.wait(lambda: w.worker.polls > polls + 25)  # status is read every 10th poll
    warnings = [t for level, t in w.logs if level == "warn" and "status 99" in t]
    assert len(warnings) == 1 and "unknown to the driver" in warnings[0]


class Requests:
    """Every request the emulator handles, in order (its first bytes)."""

    def __init__(self, emulator):
        self.log: list[bytes] = []
        handle = emulator.model.handle

        def recording(request):
            self.log.append(bytes(request[:3]))
            return handle(request)

        emulator.model.handle = recording

    FLUSH = p.motor_command(p.ALL_MOTORS, p.FLAG_FLUSH).payload[:3]
    READ_STATUS = p.read_status().payload[:3]

    def since(self, mark: int) -> list[bytes]:
        return self.log[mark:]


def _play(w, goal, seconds=2.0):
    """Stream a trajectory from where the arm is to ``goal`` and wait until every arm motor
    reports done after its end; the worker's state then."""
    plan = plan_trajectory(MODEL, w.worker.state.encoders, [seconds], [goal])
    with w.worker.busy():
        stream = w.worker.start_trajectory(plan)
        t0 = stream.started.result(timeout=5)
        stream.finished_sending.result(timeout=10)
        end = t0 + stream.lag_s + plan.duration_s
        assert w.wait(lambda: w.worker.state.status_stamp > end and all(
            s in p.REST_STATUSES for s in w.worker.state.status[:5]))
    return plan


def test_a_trajectory_after_one_that_played_out_starts_without_a_flush_or_a_read(
        make_emulator, worker_for):
    """As KNI and the ROS 1 node: no flush before a trajectory when the buffers are known
    empty, and the fingers held where the last poll found them at rest (their true place)."""
    emulator = make_emulator(calibrated=True)
    w = worker_for(emulator)
    assert w.wait(lambda: w.worker.ready)
    requests = Requests(emulator)
    _play(w, [-2.7, 1.9, -1.9, -1.7, -2.6])
    assert requests.log.count(Requests.FLUSH) == 1  # the first after the connection
    # the fingers move, then rest; a poll sees them at rest
    target = int(MODEL.gripper_angle_to_encoder(0.1))
    with w.worker.busy():
        w.worker.call(lambda client: client.gripper(target))
        assert w.wait(lambda: w.worker.state.status[5] == p.STATUS_HOLDING)
        polls = w.worker.polls
        assert w.wait(lambda: w.worker.polls > polls + 1)
    resting = emulator.model.encoders()[5]
    mark = len(requests.log)
    plan = _play(w, [-2.4, 1.7, -1.6, -1.4, -2.3])
    after = requests.since(mark)
    assert Requests.FLUSH not in after
    first_h = next(i for i, r in enumerate(after) if r[:1] == b"H")
    assert after[first_h - 1] == Requests.READ_STATUS  # a poll's read, not one of the start's
    assert w.worker._stream is None and plan.segments
    assert emulator.model.encoders()[5] == resting  # the fingers held where they rested
    assert abs(resting - target) <= 2


@pytest.mark.parametrize("left", ["a queued segment", "a collision", "a new connection"])
def test_a_trajectory_after_the_buffers_may_hold_segments_starts_with_a_flush(
        make_emulator, worker_for, left):
    emulator = make_emulator(calibrated=True)
    w = worker_for(emulator)
    assert w.wait(lambda: w.worker.ready)
    requests = Requests(emulator)
    _play(w, [-2.7, 1.9, -1.9, -1.7, -2.6])
    start = list(emulator.model.encoders())
    mark = len(requests.log)  # a flush must come after what may leave segments behind
    if left == "a queued segment":  # sent by hand, never started: it would play first
        stale = plan_trajectory(MODEL, start, [3.0], [[-1.5, 1.9, -1.9, -1.7, -2.6]])
        row = [*stale.segments[0], hold_segment(start[5], stale.segments[0][0].duration)]
        w.worker.call(lambda client: client.send_spline_all(row, p.ACTIVITY_QUEUE))
    elif left == "a collision":
        emulator.model.collision_detection = True
        assert emulator.model.inject_collision(2)
        assert w.wait(lambda: bool(w.worker.collision_message))
    else:
        emulator.drop_connection()
        assert w.wait(lambda: any("lost connection" in t for _, t in w.logs))
        assert w.wait(lambda: w.worker.ready and w.worker.connected)
    with w.worker.busy():
        polls = w.worker.polls
        assert w.wait(lambda: w.worker.polls > polls + 1)
    goal = [-2.8, 1.95, -1.95, -1.75, -2.65]
    highest = []
    w.worker.on_state = lambda state: highest.append(state.positions[0])
    played_from = len(requests.log)
    _play(w, goal)
    first_h = next(i for i in range(played_from, len(requests.log))
                   if requests.log[i][:1] == b"H")
    assert Requests.FLUSH in requests.log[mark:first_h]
    assert w.worker.state.positions[:5] == pytest.approx(goal, abs=2e-3)
    # the pan never went towards the stale segment's -1.5 rad
    assert max(highest) < MODEL.encoders_to_joint_positions(start)[0] + 0.01
