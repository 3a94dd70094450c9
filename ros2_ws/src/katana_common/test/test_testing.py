"""katana_common.testing's bounded waits (spin_until, wait_until, call_service) and
stop_process."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
from types import SimpleNamespace

import pytest
from katana_common import testing
from katana_common.testing import (
    call_service,
    probe_node,
    spin_until,
    stop_process,
    wait_for_output,
    wait_until,
)
from rcl_interfaces.msg import ParameterValue
from rcl_interfaces.srv import GetParameters


class FakeClock:
    """Time that passes only when an executor spins (no timing of the machine in the test)."""

    def __init__(self) -> None:
        self.now = 100.0

    def monotonic(self) -> float:
        return self.now


class FakeExecutor:
    """Records the slices it was asked to spin, and lets them pass on `clock` as an idle
    executor would."""

    def __init__(self, clock: FakeClock | None = None) -> None:
        self.slices: list[float] = []
        self.clock = clock

    def spin_once(self, timeout_sec: float | None = None) -> None:
        self.slices.append(timeout_sec)
        if self.clock is not None:
            self.clock.now += timeout_sec


def test_spin_until_returns_at_once_without_spinning_when_the_condition_holds():
    executor = FakeExecutor()
    assert spin_until(executor, lambda: "ready", timeout_s=5.0) == "ready"
    assert executor.slices == []


def test_spin_until_spins_until_the_condition_holds_and_returns_its_value():
    executor = FakeExecutor()
    assert spin_until(executor, lambda: len(executor.slices) >= 3 and [1], slice_s=0.001) == [1]
    assert executor.slices == [0.001] * 3


@pytest.mark.parametrize("falsy", [False, None, 0, []])
def test_spin_until_gives_up_at_the_deadline_with_the_last_value(falsy, monkeypatch):
    clock = FakeClock()
    monkeypatch.setattr(testing, "time", SimpleNamespace(monotonic=clock.monotonic))
    executor = FakeExecutor(clock)
    assert spin_until(executor, lambda: falsy, timeout_s=0.12, slice_s=0.05) == falsy
    assert executor.slices == pytest.approx([0.05, 0.05, 0.02])  # the last slice cut short
    assert clock.now == pytest.approx(100.12)


def test_spin_until_runs_the_callbacks_of_a_real_executor():
    with probe_node("spin_until_probe") as (node, executor):
        fired: list[int] = []
        node.create_timer(0.01, lambda: fired.append(1))
        assert spin_until(executor, lambda: len(fired) >= 3, timeout_s=5.0)
        assert not spin_until(executor, lambda: False, timeout_s=0.05)


def test_call_service_waits_for_the_service_and_its_answer():
    def answer(req, res):
        res.values = [ParameterValue(string_value=f"asked for {req.names[0]}")]
        return res

    with probe_node("call_service_probe") as (node, executor):
        client = node.create_client(GetParameters, "probe_service")
        request = GetParameters.Request(names=["x"])
        with pytest.raises(TimeoutError, match="probe_service not available"):
            call_service(executor, client, request, timeout_s=0.1)
        node.create_service(GetParameters, "probe_service", answer)
        assert call_service(executor, client, request).values[0].string_value == "asked for x"


def test_wait_until_sees_what_another_thread_does():
    flag = threading.Event()
    threading.Timer(0.05, flag.set).start()
    assert wait_until(flag.is_set, timeout_s=5.0) is True  # False after 5 s if never seen


def test_wait_until_returns_the_value_or_gives_up_at_the_deadline(monkeypatch):
    assert wait_until(lambda: 7) == 7
    clock = FakeClock()

    def sleep(seconds: float) -> None:
        clock.now += seconds

    monkeypatch.setattr(testing, "time", SimpleNamespace(monotonic=clock.monotonic, sleep=sleep))
    calls: list[float] = []
    # binary fractions: the fake time adds up exactly
    assert testing.wait_until(lambda: calls.append(clock.now), timeout_s=0.5,
                              poll_s=0.125) is None
    assert calls == [100.0, 100.125, 100.25, 100.375, 100.5]  # every poll_s, to the deadline


def _python(body: str) -> subprocess.Popen:
    """A Python process running `body` that prints "ready" once its signal handlers are set."""
    proc = subprocess.Popen([sys.executable, "-c", body], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    assert proc.stdout.readline() == "ready\n"
    return proc


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_stop_process_times_a_clean_exit_and_returns_its_output(sig):
    proc = _python(
        "import signal, sys, time\n"
        "def bye(*_):\n"
        "    print('bye'); print('on stderr', file=sys.stderr); sys.exit(0)\n"
        "signal.signal(signal.SIGINT, bye); signal.signal(signal.SIGTERM, bye)\n"
        "print('ready', flush=True)\n"
        "time.sleep(60)\n")
    seconds, out, err = stop_process(proc, sig, timeout_s=10.0)
    assert proc.returncode == 0
    assert 0.0 <= seconds < 5.0
    assert (out, err) == ("bye\n", "on stderr\n")


def test_stop_process_aborts_a_process_that_ignores_the_signal_and_its_stacks_show_why():
    """Past the timeout: SIGABRT, which faulthandler (on in every process that spins nodes)
    answers with every thread's stack."""
    proc = _python(
        "import faulthandler, signal, time\n"
        "faulthandler.enable()\n"
        "signal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
        "def stuck_here():\n"
        "    print('ready', flush=True)\n"
        "    time.sleep(60)\n"
        "stuck_here()\n")
    seconds, out, err = stop_process(proc, signal.SIGTERM, timeout_s=0.3)
    assert proc.returncode == -signal.SIGABRT
    assert 0.3 <= seconds < 5.0
    assert out == ""
    assert "Fatal Python error: Aborted" in err and "in stuck_here" in err


def test_stop_process_kills_a_process_that_ignores_the_abort_too():
    proc = _python(
        "import signal, time\n"
        "signal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
        "signal.signal(signal.SIGABRT, signal.SIG_IGN)\n"
        "print('ready', flush=True)\n"
        "time.sleep(60)\n")
    seconds, out, err = stop_process(proc, signal.SIGTERM, timeout_s=0.3, dump_s=0.3)
    assert proc.returncode == -signal.SIGKILL
    assert 0.3 <= seconds < 5.0
    assert (out, err) == ("", "")


def test_wait_for_output_finds_a_line_that_came_in_one_chunk_with_another() -> None:
    """Two lines written at once: the second is found (select() on the buffered file object
    would have waited for more after readline took both)."""
    proc = subprocess.Popen([sys.executable, "-c",
                             "import sys, time; sys.stdout.write('first\\nport 4242\\n'); "
                             "sys.stdout.flush(); time.sleep(30)"],
                            stdout=subprocess.PIPE, text=True)
    try:
        found = wait_for_output(proc.stdout, r"port (\d+)", 20.0)
        assert found and found.group(1) == "4242"
        assert wait_for_output(proc.stdout, r"never", 0.3) is None
    finally:
        proc.kill()
        proc.wait()
        proc.stdout.close()
