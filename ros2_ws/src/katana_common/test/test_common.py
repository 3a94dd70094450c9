"""katana_common: parameters, declaration, live updates, the runner, messages, futures."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
import uuid

import pytest
import rclpy
from builtin_interfaces.msg import Time
from control_msgs.action import GripperCommand
from hypothesis import given
from hypothesis import strategies as st
from katana_common.action_client import ActionClient
from katana_common.executor import MultiThreadedExecutor
from katana_common.futures import NumberedArrivals, Stopped, wait_for_future
from katana_common.messages import duration_msg, time_msg, to_nanoseconds, to_seconds
from katana_common.node_runner import (
    EXIT_FAILURE,
    EXIT_INVALID_CONFIGURATION,
    EXIT_OK,
    SHUTDOWN_LIMIT_S,
    STACK_DUMP_GRACE_S,
)
from katana_common.param_spec import Param
from katana_common.params import ParameterError, declare_parameters
from katana_common.testing import private_ros_env
from rclpy.action import ActionServer
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.task import Future

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")

PARAMS = (
    Param("alpha", 1.0, "query scale", low=1e-3, high=100.0, live=True),
    Param("strategy", "q1", "strategy", choices=("q1", "random"), live=True),
    Param("max_height", 3, "top height", low=0, high=7),
    Param("reach", [0.3, 0.2], "reach per level", low=0.0, high=1.0, min_length=1),
    Param("run_dir", "runs/x", "folder", nonempty=True),
)


# -- Param.problem: independent of ROS --------------------------------------------------------
@given(st.floats(allow_nan=True, allow_infinity=True))
def test_float_range_matches_a_direct_comparison(value):
    spec = PARAMS[0]
    ok = math.isfinite(value) and 1e-3 <= value <= 100.0
    assert (spec.problem(value) is None) == ok


@given(st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=4))
def test_list_bounds_every_element_and_the_length(values):
    spec = PARAMS[3]
    ok = len(values) >= 1 and all(math.isfinite(v) and 0.0 <= v <= 1.0 for v in values)
    assert (spec.problem(values) is None) == ok


@given(st.text(max_size=8))
def test_choices_accept_only_the_listed_values(value):
    assert (PARAMS[1].problem(value) is None) == (value in ("q1", "random"))


def test_a_bool_is_not_a_number_and_empty_text_is_refused():
    assert PARAMS[2].problem(True) is not None
    assert PARAMS[4].problem("") is not None
    assert Param("flag", False, "a flag").problem(1) is not None


def test_valid_text_names_range_choices_and_length():
    assert "[0.001, 100]" in PARAMS[0].valid_text()
    assert "'q1', 'random'" in PARAMS[1].valid_text()
    assert "at least 1" in PARAMS[3].valid_text()
    assert not PARAMS[0].descriptor().read_only
    assert PARAMS[2].descriptor().read_only


# -- declaration on a node --------------------------------------------------------------------
@pytest.fixture
def context():
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    try:
        yield ctx
    finally:
        rclpy.try_shutdown(context=ctx)


def _node(context, overrides=()):
    return Node(
        f"params_{uuid.uuid4().hex[:8]}",
        context=context,
        parameter_overrides=[Parameter(k, value=v) for k, v in overrides],
    )


def test_defaults_are_declared_and_read_back(context):
    node = _node(context)
    params = declare_parameters(node, PARAMS)
    assert params["alpha"] == 1.0 and params["reach"] == [0.3, 0.2]
    assert node.get_parameter("strategy").value == "q1"
    node.destroy_node()


@pytest.mark.parametrize(
    "name, value",
    [
        ("alpha", 0.0),
        ("alpha", 1e9),
        ("strategy", "bogus"),
        ("max_height", 9),
        ("reach", [0.1, 2.0]),
        ("run_dir", ""),
        ("alpha", "text"),
    ],
)
def test_an_invalid_override_names_the_parameter_and_its_valid_values(context, name, value):
    node = _node(context, [(name, value)])
    with pytest.raises(ParameterError) as err:
        declare_parameters(node, PARAMS)
    assert f"'{name}'" in str(err.value) and "valid" in str(err.value)
    node.destroy_node()


def test_an_unknown_override_is_refused_but_scene_names_are_tolerated(context):
    node = _node(context, [("alhpa", 2.0)])
    with pytest.raises(ParameterError, match="unknown parameter 'alhpa'"):
        declare_parameters(node, PARAMS)
    node.destroy_node()
    node = _node(context, [("block_size", [0.04, 0.04, 0.03]), ("world_frame", "world")])
    declare_parameters(node, PARAMS)
    node.destroy_node()


def test_cross_check_applies_at_start_up_and_live(context):
    def rule(values):
        return None if values["alpha"] < 50 else "alpha must stay below 50 here"

    node = _node(context, [("alpha", 60.0)])
    with pytest.raises(ParameterError, match="below 50"):
        declare_parameters(node, PARAMS, cross_check=rule)
    node.destroy_node()
    node = _node(context)
    params = declare_parameters(node, PARAMS, cross_check=rule)
    result = node.set_parameters([Parameter("alpha", value=70.0)])[0]
    assert not result.successful and "below 50" in result.reason
    assert params["alpha"] == 1.0
    node.destroy_node()


def test_live_changes_through_the_parameter_service(context):
    """What `ros2 param set` does: the SetParameters service, through rclpy's client."""
    server = _node(context)
    params = declare_parameters(server, PARAMS)
    seen = []
    params.on_change(seen.append)
    client_node = _node(context)
    client = AsyncParameterClient(client_node, server.get_name())
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(server)
    executor.add_node(client_node)
    assert client.wait_for_services(timeout_sec=5.0)

    def set_one(name, value):
        future = client.set_parameters([Parameter(name, value=value)])
        executor.spin_until_future_complete(future, timeout_sec=5.0)
        assert future.done()
        return future.result().results[0]

    ok = set_one("alpha", 2.0)
    assert ok.successful
    assert params["alpha"] == 2.0 and seen == [{"alpha": 2.0}]
    bad = set_one("strategy", "bogus")
    assert not bad.successful and "strategy" in bad.reason
    assert params["strategy"] == "q1" and server.get_parameter("strategy").value == "q1"
    read_only = set_one("max_height", 2)
    assert not read_only.successful
    assert params["max_height"] == 3 and server.get_parameter("max_height").value == 3
    assert len(seen) == 1
    executor.shutdown()
    client_node.destroy_node()
    server.destroy_node()


# -- the runner, as `ros2 run` and `ros2 launch` meet it --------------------------------------
NODE_SCRIPT = textwrap.dedent(
    """
    import sys
    from katana_common.node_runner import run_node
    from katana_common.param_spec import Param
    from katana_common.params import declare_parameters
    from rclpy.node import Node

    class Demo(Node):
        def __init__(self):
            super().__init__("runner_demo")
            self.params = declare_parameters(self, [Param("rate", 1.0, "Hz", low=0.1, high=9)])
            # "ready" once spinning, so the test's signal meets a running node
            self.timer = self.create_timer(0.01, self.ready)

        def ready(self):
            self.timer.cancel()
            print("ready", flush=True)

        def stop(self):
            print("stopping", flush=True)

    sys.exit(run_node(Demo, "runner_demo", args=sys.argv))
    """
)


def _start(*ros_args):
    # a domain of this test process alone, so parallel runs on one machine cannot meet
    env = private_ros_env()
    return subprocess.Popen(
        [sys.executable, "-c", NODE_SCRIPT, "--ros-args", *ros_args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )


def test_a_bad_parameter_exits_2_with_one_line_naming_it():
    proc = _start("-p", "rate:=50.0")
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == EXIT_INVALID_CONFIGURATION
    assert "parameter 'rate'" in err and "Traceback" not in err


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_stops_the_node_cleanly(sig):
    proc = _start()
    assert proc.stdout.readline().strip() == "ready"
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=10)
    assert proc.returncode == EXIT_OK, err
    assert "stopping" in out and "Traceback" not in err


def test_a_node_process_prints_every_threads_stack_on_sigabrt():
    """What katana_common.testing.stop_process sends a node that outlives its signal."""
    proc = _start()
    assert proc.stdout.readline().strip() == "ready"
    proc.send_signal(signal.SIGABRT)
    out, err = proc.communicate(timeout=10)
    assert proc.returncode == -signal.SIGABRT
    assert "Fatal Python error: Aborted" in err and "in spin_nodes" in err


def test_a_stop_stuck_holding_the_gil_ends_the_process_with_every_stack():
    """A C call that holds the GIL keeps the Python watchdog from running; faulthandler's
    watchdog still ends the process (exit 1) and shows where it was stuck."""
    stuck = NODE_SCRIPT.replace(
        'print("stopping", flush=True)',
        'print("stopping", flush=True)\n'
        '        import ctypes\n'
        '        ctypes.PyDLL(None).sleep(60)  # libc sleep(), the GIL held')
    proc = subprocess.Popen([sys.executable, "-c", stuck], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=private_ros_env())
    try:
        assert proc.stdout.readline().strip() == "ready"
        start = time.monotonic()
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
        took = time.monotonic() - start
    finally:
        proc.kill()  # a no-op once it has ended
    assert proc.returncode == EXIT_FAILURE, err
    assert "stopping" in out
    assert "Timeout" in err and "in stop" in err  # faulthandler's dump, the stuck frame in it
    assert took < SHUTDOWN_LIMIT_S + STACK_DUMP_GRACE_S + 5.0


# -- messages and futures ---------------------------------------------------------------------
@given(st.floats(min_value=0.0, max_value=4e9))
def test_time_round_trips_to_the_nanosecond(seconds):
    msg = time_msg(seconds)
    assert 0 <= msg.nanosec < 1_000_000_000
    assert abs(to_seconds(msg) - seconds) <= 1e-9 + abs(seconds) * 1e-15


@given(st.integers(0, 2**31 - 1), st.integers(0, 999_999_999))
def test_nanoseconds_of_a_stamp_are_exact(sec, nanosec):
    stamp = Time(sec=sec, nanosec=nanosec)
    assert to_nanoseconds(stamp) == sec * 1_000_000_000 + nanosec  # beyond a float's 2**53
    assert divmod(to_nanoseconds(stamp), 1_000_000_000) == (sec, nanosec)


@given(st.floats(min_value=-1e6, max_value=1e6))
def test_negative_durations_keep_nanosec_in_range(seconds):
    msg = duration_msg(seconds)
    assert 0 <= msg.nanosec < 1_000_000_000
    assert abs(to_seconds(msg) - seconds) <= 1e-9 + abs(seconds) * 1e-15


def test_non_finite_and_negative_stamps_are_refused():
    with pytest.raises(ValueError):
        time_msg(-1.0)
    with pytest.raises(ValueError):
        duration_msg(float("nan"))


def test_wait_for_future_returns_times_out_and_stops():
    done = Future()
    threading.Timer(0.05, lambda: done.set_result(7)).start()
    assert wait_for_future(done, 2.0, "answer") == 7
    late = Future()
    with pytest.raises(TimeoutError, match="late"):
        wait_for_future(late, 0.05, "late")
    assert late.cancelled()
    stop = threading.Event()
    threading.Timer(0.05, stop.set).start()
    start = time.monotonic()
    with pytest.raises(Stopped):
        wait_for_future(Future(), 30.0, "stopped", stop=stop)
    assert time.monotonic() - start < 30.0


def test_numbered_arrivals_wait_for_a_number_or_a_later_one():
    arrivals = NumberedArrivals()
    assert arrivals.wait_for(0, 0.0)  # nothing named: in at once
    assert not arrivals.wait_for(1, 0.05)
    threading.Timer(0.05, arrivals.arrived, (3,)).start()
    start = time.monotonic()
    assert arrivals.wait_for(2, 5.0)  # a later one will do
    assert 0.04 <= time.monotonic() - start < 5.0 and arrivals.number == 3
    assert not arrivals.wait_for(4, 0.05)


class _SlowToRegister:
    """A client handle that pauses after sending a request, before the client registers the
    request's future: the executor's thread takes and executes the response meanwhile."""

    def __init__(self, handle, pause_s: float) -> None:
        self._handle, self._pause_s = handle, pause_s

    def __getattr__(self, name):
        attr = getattr(self._handle, name)
        if name.startswith("send_"):
            def sent(*args, **kwargs):
                out = attr(*args, **kwargs)
                time.sleep(self._pause_s)
                return out
            return sent
        return attr


def test_the_action_client_completes_a_goal_answered_before_its_future_is_registered():
    """rclpy#1123: with rclpy's ActionClient such a response is ignored and the future never
    completes; katana_common's client holds the executor back until the future is known."""
    def execute(goal_handle):
        goal_handle.succeed()
        return GripperCommand.Result(position=goal_handle.request.command.position)

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    server_node = Node("race_server", context=ctx)
    client_node = Node("race_client", context=ctx)
    server = ActionServer(server_node, GripperCommand, "grip", execute)
    client = ActionClient(client_node, GripperCommand, "grip")
    executor = MultiThreadedExecutor(num_threads=2, context=ctx)
    executor.add_node(server_node)
    executor.add_node(client_node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        assert client.wait_for_server(timeout_sec=10.0)
        client._client_handle = _SlowToRegister(client._client_handle, 0.3)
        for position in (0.1, 0.2):
            goal = GripperCommand.Goal()
            goal.command.position = position
            sent = client.send_goal_async(goal)
            handle = wait_for_future(sent, 10.0, "goal response")
            assert handle.accepted
            result = wait_for_future(handle.get_result_async(), 10.0, "result")
            assert result.result.position == position
    finally:
        executor.shutdown(timeout_sec=5)
        server.destroy()
        client.destroy()
        server_node.destroy_node()
        client_node.destroy_node()
        rclpy.try_shutdown(context=ctx)
