"""katana_driver_node's lifecycle in-process against the emulator, driven through its
lifecycle_msgs services (~/change_state, ~/get_state) as a lifecycle manager drives it: what each
transition does to the link, the calibration, the goals and the arm (the emulator's own motor
states are the ground truth)."""

import itertools
import sys
import time
from pathlib import Path

import pytest
from control_msgs.action import FollowJointTrajectory
from diagnostic_msgs.msg import DiagnosticArray
from katana_common.health import OK, WARN
from katana_common.qos import DIAGNOSTICS_QOS
from katana_driver.core import protocol as p
from katana_driver.health import driver_health
from lifecycle_msgs.msg import State, Transition, TransitionEvent
from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.action.client import GoalStatus
from rclpy.qos import QoSProfile
from std_msgs.msg import Bool

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib
from test_driver_node import Graph, gripper_goal, trajectory_goal  # noqa: E402

pytestmark = pytest.mark.timeout(120)
_ids = itertools.count()
#: a 3 s move of every arm joint from the backed-off pose: long enough to stop it midway
FAR = [(3.0, [-1.5, 1.2, -1.0, -0.5, -1.5])]
NEAR = [(2.0, [-2.5, 1.8, -1.8, -1.5, -2.5])]


class Lifecycle(Graph):
    """Graph plus lifecycle service clients, the driver's transition events and arm_ready."""

    def __init__(self, emulator, **params):
        super().__init__(emulator, **params)
        base = self.driver.get_name()
        self.change = self.client.create_client(ChangeState, f"{base}/change_state")
        self.get = self.client.create_client(GetState, f"{base}/get_state")
        self.events: list[TransitionEvent] = []
        self.client.create_subscription(TransitionEvent, f"{base}/transition_event",
                                        self.events.append, QoSProfile(depth=50))
        self.arm_ready: list[bool] = []
        self.client.create_subscription(Bool, "arm_ready", lambda m: self.arm_ready.append(
            m.data), self.driver._ready_pub.qos_profile)

    def set(self, transition_id: int) -> bool:
        request = ChangeState.Request(transition=Transition(id=transition_id))
        return self.call(self.change, request).success

    def state(self) -> str:
        return self.call(self.get, GetState.Request()).current_state.label

    def refusal(self, points=NEAR) -> str:
        res = self.run_goal(self.arm, trajectory_goal(points))
        assert res.status == GoalStatus.STATUS_ABORTED
        assert res.result.error_code == FollowJointTrajectory.Result.INVALID_GOAL
        return res.result.error_string

    def moving(self):
        """Send FAR and wait until motor 1 moves; the goal's result future."""
        sent = self.arm.send_goal_async(trajectory_goal(FAR))
        assert self.spin_until(sent.done) and sent.result().accepted
        result = sent.result().get_result_async()
        assert self.spin_until(lambda: self.emulator.model.statuses()[0] == p.STATUS_MOVING)
        return result


@pytest.fixture
def lifecycle(make_emulator):
    made = []

    def make(emulator=None, **params):
        g = Lifecycle(emulator or make_emulator(), **{"autostart": False, **params})
        made.append(g)
        assert g.spin_until(lambda: g.change.service_is_ready() and g.get.service_is_ready())
        assert g.spin_until(g.arm.server_is_ready)
        return g

    yield make
    for g in made:
        g.close()


def _frozen(g) -> bool:
    return [m.status for m in g.emulator.model.motors] == [p.STATUS_HOLDING] * 6


def test_each_transition_does_what_its_state_means(lifecycle):
    """unconfigured: no link, goals refused; configure: link, version, no motion; activate:
    calibrated, goals run, arm_ready; deactivate: refused again; cleanup: link closed;
    shutdown: finalized."""
    g = lifecycle()
    emulator = g.emulator
    assert g.state() == "unconfigured" and not g.driver.worker.connected
    assert "unconfigured, not active" in g.refusal()
    assert "no connection to the Katana controller" in g.refusal()

    assert g.set(Transition.TRANSITION_CONFIGURE)
    assert g.state() == "inactive"
    assert g.driver.worker.connected and g.driver.worker.master_version is not None
    assert g.driver.worker.identification
    assert emulator.model.calibrations == 0  # configure reads; it does not move or calibrate
    assert "inactive, not active" in g.refusal()
    res = g.run_goal(g.gripper, gripper_goal(-0.2))
    assert res.status == GoalStatus.STATUS_ABORTED and not res.result.reached_goal
    assert emulator.model.calibrations == 0
    health = driver_health(g.driver.worker, g.driver.lifecycle_state())
    assert health.level == WARN and "inactive: goals are refused" in health.message

    assert g.set(Transition.TRANSITION_ACTIVATE)
    assert g.state() == "active" and g.driver.ready
    assert emulator.model.calibrations == 1 and g.driver.worker.calibrated
    assert g.spin_until(lambda: g.arm_ready and g.arm_ready[-1] is True)
    res = g.run_goal(g.arm, trajectory_goal(NEAR))
    assert res.status == GoalStatus.STATUS_SUCCEEDED, res.result.error_string
    assert driver_health(g.driver.worker, g.driver.lifecycle_state()).level == OK

    assert g.set(Transition.TRANSITION_DEACTIVATE)
    assert g.state() == "inactive" and g.driver.worker.connected
    assert g.spin_until(lambda: g.arm_ready[-1] is False)
    assert "inactive, not active" in g.refusal()
    count = len(g.states)  # joint_states keep flowing while inactive (viewers)
    assert g.spin_until(lambda: len(g.states) > count + 3)

    assert g.set(Transition.TRANSITION_CLEANUP)
    assert g.state() == "unconfigured"
    assert not g.driver.worker.connected and not g.driver.worker.running
    assert "no connection to the Katana controller" in g.refusal()

    assert g.set(Transition.TRANSITION_UNCONFIGURED_SHUTDOWN)
    assert g.state() == "finalized"
    labels = [(e.start_state.label, e.goal_state.label) for e in g.events]
    assert ("shuttingdown", "finalized") in labels and ("activating", "active") in labels


def test_a_transition_the_state_does_not_offer_is_refused(lifecycle):
    """rclpy raises for it in the service callback; the driver answers success false."""
    g = lifecycle()
    assert not g.set(Transition.TRANSITION_ACTIVATE)  # unconfigured: configure first
    assert g.state() == "unconfigured" and not g.driver.worker.running
    assert g.set(Transition.TRANSITION_CONFIGURE)  # the node goes on serving


def test_configure_without_a_controller_fails_and_stays_unconfigured(lifecycle, make_emulator):
    emulator = make_emulator()
    emulator.stop()
    g = lifecycle(emulator)
    assert not g.set(Transition.TRANSITION_CONFIGURE)
    assert g.state() == "unconfigured" and not g.driver.worker.running


def test_configure_refuses_a_controller_kni_refuses_as_a_450(lifecycle, make_emulator):
    """A master version above 3 (KNI exits: "Incompatible Config File"): configure fails with
    the reason, the link is closed, and the controller was sent no command."""
    emulator = make_emulator()
    emulator.model.master_version = (4, 0)
    speed_limits = [m.speed_limit for m in emulator.model.motors]
    g = lifecycle(emulator)
    assert not g.set(Transition.TRANSITION_CONFIGURE)
    assert g.state() == "unconfigured" and not g.driver.worker.running
    assert "master version 4 is above 3" in g.driver.worker.controller_refusal
    assert emulator.model.calibrations == 0
    assert [m.speed_limit for m in emulator.model.motors] == speed_limits


def test_deactivate_freezes_an_arm_in_motion(lifecycle, make_emulator):
    g = lifecycle(make_emulator(calibrated=True))
    assert g.set(Transition.TRANSITION_CONFIGURE) and g.set(Transition.TRANSITION_ACTIVATE)
    result = g.moving()
    before = g.emulator.model.statuses()
    assert g.set(Transition.TRANSITION_DEACTIVATE)
    assert p.STATUS_MOVING in before and _frozen(g)  # the emulated motors stopped
    assert g.spin_until(result.done)
    res = result.result()
    assert res.status == GoalStatus.STATUS_ABORTED
    assert "deactivated" in res.result.error_string
    encoders = list(g.emulator.model.encoders())
    g.spin_until(lambda: False, timeout_s=0.3)  # no queued segment plays on
    assert g.emulator.model.encoders() == encoders
    assert "inactive, not active" in g.refusal()


def test_a_silent_controller_lands_in_error_processing_with_the_arm_frozen(lifecycle,
                                                                          make_emulator):
    """The controller stops answering mid-trajectory: the link is lost, the node goes
    active -> errorprocessing -> unconfigured, and the arm is frozen once it answers again."""
    g = lifecycle(make_emulator(calibrated=True), timeout=0.2, retries=1)
    assert g.set(Transition.TRANSITION_CONFIGURE) and g.set(Transition.TRANSITION_ACTIVATE)
    result = g.moving()
    g.emulator.faults.silent_until = time.monotonic() + 1.5
    assert g.spin_until(lambda: any(e.goal_state.id == State.TRANSITION_STATE_ERRORPROCESSING
                                    for e in g.events))
    assert g.spin_until(lambda: g.events[-1].goal_state.label == "unconfigured")
    assert g.state() == "unconfigured" and not g.driver.worker.running
    assert _frozen(g)
    assert g.spin_until(result.done)
    assert result.result().status == GoalStatus.STATUS_ABORTED
    assert g.arm_ready[-1] is False
    g.spin_until(lambda: False, timeout_s=1.0)  # five keeper periods: autostart false,
    assert g.state() == "unconfigured"          # nothing brings it up again


def test_a_lost_link_while_inactive_is_an_error_too(lifecycle, make_emulator):
    """inactive -> errorprocessing -> unconfigured (rclpy offers no error transition from a
    primary state: the driver's cleanup answers ERROR)."""
    g = lifecycle(make_emulator(calibrated=True))
    assert g.set(Transition.TRANSITION_CONFIGURE)
    g.emulator.drop_connection()
    assert g.spin_until(lambda: [(e.start_state.label, e.goal_state.label) for e in g.events][-2:]
                        == [("cleaningup", "errorprocessing"),
                            ("errorprocessing", "unconfigured")])
    assert g.state() == "unconfigured" and not g.driver.worker.running
    assert g.emulator.model.calibrations == 0 and _frozen(g)


def test_a_reconnection_after_cleanup_does_not_recalibrate(lifecycle):
    g = lifecycle()
    assert g.set(Transition.TRANSITION_CONFIGURE) and g.set(Transition.TRANSITION_ACTIVATE)
    assert g.emulator.model.calibrations == 1
    for transition in (Transition.TRANSITION_DEACTIVATE, Transition.TRANSITION_CLEANUP,
                       Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE):
        assert g.set(transition)
    assert g.state() == "active" and g.driver.ready
    assert g.emulator.model.calibrations == 1  # the probe found the arm calibrated
    res = g.run_goal(g.arm, trajectory_goal(NEAR))
    assert res.status == GoalStatus.STATUS_SUCCEEDED, res.result.error_string


def test_autostart_activates_and_comes_back_after_an_error(lifecycle):
    """The default: active by itself; after a lost link, errorprocessing, then active again
    without calibrating again; a user's deactivate is not undone."""
    g = lifecycle(autostart=True)
    g.ready()
    assert g.driver.lifecycle_state() == "active" and g.emulator.model.calibrations == 1
    g.emulator.drop_connection()
    assert g.spin_until(lambda: g.driver.worker.link_losses == 1)
    assert g.spin_until(lambda: g.driver.ready)
    assert g.emulator.model.calibrations == 1

    def back_to_active() -> bool:
        labels = [e.goal_state.label for e in g.events]
        return "errorprocessing" in labels and "active" in labels[labels.index("errorprocessing"):]

    assert g.spin_until(back_to_active)
    assert g.set(Transition.TRANSITION_DEACTIVATE)  # as a lifecycle manager's request would
    g.spin_until(lambda: False, timeout_s=1.0)  # five keeper periods: it stays inactive
    assert g.driver.lifecycle_state() == "inactive" and not g.driver.ready


def test_diagnostics_go_on_while_the_activation_calibrates(lifecycle, make_emulator):
    """The lifecycle services have a callback group of their own: a calibration of 2 s inside
    the activate call does not hold /diagnostics, which reports the state as activating."""
    g = lifecycle(make_emulator(calibration_s=2.0))
    assert g.set(Transition.TRANSITION_CONFIGURE)
    states: list[str] = []

    def on_diagnostics(msg):
        for status in msg.status:
            if status.name.endswith(": controller"):
                states.extend(kv.value for kv in status.values if kv.key == "lifecycle_state")

    g.client.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics,
                                 DIAGNOSTICS_QOS)
    activated = g.change.call_async(
        ChangeState.Request(transition=Transition(id=Transition.TRANSITION_ACTIVATE)))
    assert g.spin_until(lambda: "activating" in states)
    assert g.spin_until(activated.done) and activated.result().success
    assert g.emulator.model.calibrations == 1
