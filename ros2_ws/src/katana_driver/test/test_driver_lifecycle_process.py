"""katana_driver_node as a ROS user meets it: its console script in a process of its own with
autostart false, driven by lifecycle_msgs ChangeState / GetState service calls from another
process (as `ros2 lifecycle set` or a lifecycle manager does), then ended by SIGINT."""

import shutil
import signal
import sys
from pathlib import Path

import pytest
from katana_common.testing import AnswerLost, call_service, probe_node, use_private_domain
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib
from test_driver_signals import NodeProcess  # noqa: E402

pytestmark = pytest.mark.timeout(120)
T = Transition


def _driver(emulator, *extra):
    exe = shutil.which("katana_driver_node")
    assert exe, "katana_driver_node is not on PATH (source scripts/env.sh after setup.sh)"
    host, port = emulator.address
    return NodeProcess(["-u", exe, "--ros-args", "-p", f"host:={host}", "-p", f"port:={port}",
                        "-p", "autostart:=false", *extra])


#: where each transition the tests make leads
TARGET = {T.TRANSITION_CONFIGURE: "inactive", T.TRANSITION_ACTIVATE: "active",
          T.TRANSITION_DEACTIVATE: "inactive", T.TRANSITION_CLEANUP: "unconfigured",
          T.TRANSITION_ACTIVE_SHUTDOWN: "finalized"}
SERVICE_S = 30.0  # for the driver's services to appear
ANSWER_S = 10.0  # an answer not here by then was lost (katana_common.testing.AnswerLost)


class Lifecycle:
    """ChangeState and GetState as a lifecycle manager uses them: a transition is requested
    once (it is not idempotent); when its answer is lost, GetState (idempotent, so asked
    again) tells whether it happened."""

    def __init__(self, node, executor):
        self.executor = executor
        self.change = node.create_client(ChangeState, "/katana_driver_node/change_state")
        self.get = node.create_client(GetState, "/katana_driver_node/get_state")

    def set(self, transition_id: int) -> bool:
        request = ChangeState.Request(transition=Transition(id=transition_id))
        try:
            return call_service(self.executor, self.change, request, SERVICE_S,
                                ANSWER_S).success
        except AnswerLost:
            return self.state() == TARGET[transition_id]

    def state(self, tries: int = 3) -> str:
        try:
            return call_service(self.executor, self.get, GetState.Request(), SERVICE_S,
                                ANSWER_S).current_state.label
        except AnswerLost:
            if tries <= 1:
                raise
            return self.state(tries - 1)


def test_lifecycle_services_drive_the_driver_process(make_emulator, monkeypatch):
    use_private_domain(monkeypatch)
    emulator = make_emulator()
    proc = _driver(emulator)
    try:
        assert proc.wait_for("autostart false: waiting for configure"), proc.log
        with probe_node("lifecycle_probe") as (node, executor):
            lc = Lifecycle(node, executor)
            assert lc.state() == "unconfigured"
            assert lc.set(T.TRANSITION_CONFIGURE) and lc.state() == "inactive"
            assert emulator.model.calibrations == 0
            assert lc.set(T.TRANSITION_ACTIVATE) and lc.state() == "active"
            assert emulator.model.calibrations == 1
            assert proc.wait_for("arm ready"), proc.log
            assert lc.set(T.TRANSITION_DEACTIVATE) and lc.state() == "inactive"
            assert lc.set(T.TRANSITION_CLEANUP) and lc.state() == "unconfigured"
            assert lc.set(T.TRANSITION_CONFIGURE) and lc.set(T.TRANSITION_ACTIVATE)
            assert lc.state() == "active" and emulator.model.calibrations == 1
            assert lc.set(T.TRANSITION_ACTIVE_SHUTDOWN) and lc.state() == "finalized"
        assert proc.wait_for("shut down: arm frozen and link closed"), proc.log
        code = proc.stop(signal.SIGINT)
        assert code == 0, proc.log
        assert "Traceback" not in proc.log
    finally:
        if proc.proc.poll() is None:
            proc.proc.kill()
            proc.proc.wait()


@pytest.mark.parametrize("state", ["unconfigured", "inactive", "active"])
def test_sigint_ends_the_driver_in_any_state(make_emulator, monkeypatch, state):
    use_private_domain(monkeypatch)
    emulator = make_emulator(calibrated=True)
    proc = _driver(emulator)
    try:
        assert proc.wait_for("autostart false: waiting for configure"), proc.log
        with probe_node("lifecycle_probe") as (node, executor):
            lc = Lifecycle(node, executor)
            steps = {"unconfigured": [], "inactive": [T.TRANSITION_CONFIGURE],
                     "active": [T.TRANSITION_CONFIGURE, T.TRANSITION_ACTIVATE]}[state]
            for step in steps:
                assert lc.set(step)
            assert lc.state() == state
        code = proc.stop(signal.SIGINT)
        assert code == 0, proc.log
        assert "Traceback" not in proc.log
    finally:
        if proc.proc.poll() is None:
            proc.proc.kill()
            proc.proc.wait()
