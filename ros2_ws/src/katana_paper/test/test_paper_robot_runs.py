"""katana_paper.robot_runs without a graph: ROS domains leased per run on a machine, and a
run that ends with the worker that started it."""

import os
import subprocess
import sys
import threading
import time

from katana_paper.robot_runs import leased_domain


def _pool(size: int) -> tuple[int, ...]:
    base = 180 + os.getpid() % 40  # this test process's own domains, apart from other workers
    return tuple(range(base, base + size))


def test_runs_at_the_same_time_get_different_domains() -> None:
    pool = _pool(2)
    with leased_domain(pool) as first, leased_domain(pool) as second:
        assert {first, second} == set(pool)
    with leased_domain(pool) as again:  # both released
        assert again == pool[0]


def test_a_run_waits_for_a_free_domain_and_gets_the_one_released() -> None:
    pool = _pool(1)
    got: list[int] = []
    released = threading.Event()

    def second_run() -> None:
        with leased_domain(pool, poll_s=0.01) as domain:
            got.append(domain)
            assert released.is_set(), "leased while the first run still held it"

    with leased_domain(pool) as domain:
        waiter = threading.Thread(target=second_run)
        waiter.start()
        time.sleep(0.2)
        assert not got, "the second run did not wait"
        released.set()
    waiter.join(timeout=5.0)
    assert got == [domain]


def test_a_lease_is_released_when_the_run_fails() -> None:
    pool = _pool(1)
    try:
        with leased_domain(pool):
            raise RuntimeError("the run failed")
    except RuntimeError:
        pass
    with leased_domain(pool) as domain:
        assert domain == pool[0]


# The marker is written beside and renamed: the test polls for it, and a file that exists
# before its text is written was read empty (the test failed about once in a full-suite run).
CHILD = """
import os, signal, sys, time
from pathlib import Path
def interrupted(*_):
    Path(sys.argv[1] + ".tmp").write_text("SIGINT")
    os.replace(sys.argv[1] + ".tmp", sys.argv[1])
    sys.exit(0)
signal.signal(signal.SIGINT, interrupted)
Path(sys.argv[1] + ".ready").write_text("")
time.sleep(30)
"""

PARENT = """
import subprocess, sys, time
from katana_paper.robot_runs import _die_with_parent
subprocess.Popen([sys.executable, "-c", sys.argv[1], sys.argv[2]], preexec_fn=_die_with_parent)
time.sleep(30)
"""


def test_a_run_is_interrupted_when_the_worker_that_started_it_is_killed(tmp_path) -> None:
    """A Ray worker killed by a cancel or a shutdown takes its katana-demo with it (SIGINT, so
    that the run keeps what it recorded) rather than leaving it running."""
    marker = tmp_path / "child"
    parent = subprocess.Popen([sys.executable, "-c", PARENT, CHILD, str(marker)])
    deadline = time.monotonic() + 20.0
    while not (tmp_path / "child.ready").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert (tmp_path / "child.ready").exists(), "the child never started"
    parent.kill()
    parent.wait()
    while not marker.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert marker.read_text() == "SIGINT"
