"""The one way nodes are run and stopped: `run_node` (one node, every node's main()) and
`spin_nodes` (any set of nodes on one executor, sharing one /clock subscription: katana-run,
katana-demo).

Exit codes, for every node and console tool of the project:
0 a clean stop (including SIGINT / SIGTERM), 1 a failure while running,
2 an invalid configuration (a parameter or argument outside its valid values; as argparse).

Shutdown: rclpy's own signal handler would shut the context down under running callbacks
(publishers invalid, action servers raising), so rclpy is initialised without it and SIGINT /
SIGTERM only set an event. Then, in this order and while the context is still valid: each
node's `stop()` (if it has one: it ends the node's long waits and threads), the executor, the
nodes, the context. Bounded: after SHUTDOWN_LIMIT_S the process says what is still busy and
exits, so a stuck callback cannot keep a launch waiting for its SIGKILL. That watchdog is a
Python thread, which a thread holding the GIL in a C call that never returns keeps from running;
faulthandler's watchdog needs no GIL: STACK_DUMP_GRACE_S later it prints every thread's stack
and exits 1. faulthandler is on in every process that spins nodes, so SIGABRT (what
katana_common.testing.stop_process sends a process that outlives its signal) prints the stacks
too.
"""

from __future__ import annotations

import faulthandler
import os
import re
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence

import rclpy
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from .executor import MultiThreadedExecutor
from .params import ParameterError
from .shared_clock import SharedClock

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_INVALID_CONFIGURATION = 2

#: longest wait for the nodes' threads after a stop request, s (a node ends within 2 s)
SHUTDOWN_LIMIT_S = 1.8
#: the executor thread checks for a stop between slices of this many seconds of waiting
SPIN_SLICE_S = 0.05
#: faulthandler's watchdog (which needs no GIL) fires this long after the Python one, s
STACK_DUMP_GRACE_S = 1.0


def run_node(
    make_node: Callable[[], Node],
    name: str,
    args: list[str] | None = None,
    executor_factory: Callable[[], Executor] = MultiThreadedExecutor,
    shutdown_timeout_s: float = 1.0,
) -> int:
    """Create the node, spin it until a signal, stop it; return the exit code. A command line
    rclpy cannot parse, or one with anything but ROS arguments, is refused first (exit 2)."""
    problem = ros_args_problem(sys.argv if args is None else args)
    if problem:
        print(f"usage: {name} [--ros-args ...]\n{name}: error: {problem}", file=sys.stderr)
        return EXIT_INVALID_CONFIGURATION
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = _stop_on_signals()
    try:
        node = make_node()
    except ParameterError as err:
        rclpy.logging.get_logger(name).fatal(str(err))
        rclpy.try_shutdown()
        return EXIT_INVALID_CONFIGURATION
    return spin_nodes([node], name, executor=executor_factory(), stop=stop,
                      shutdown_timeout_s=shutdown_timeout_s)


def ros_args_problem(argv: Sequence[str]) -> str | None:
    """Why rclpy.init would refuse `argv` (argv[0] is the program), or the arguments in it that
    are not ROS arguments; None when it is fine. Nothing is initialised."""
    try:
        rest = remove_ros_args(list(argv) or ["prog"])[1:]
    except RuntimeError as err:  # rclpy's RCLInvalidROSArgsError, UnknownROSArgsError
        text = re.sub(r", at /\S+", "", " ".join(str(err).split()))
        if type(err).__name__ == "UnknownROSArgsError":  # its text is the list of them
            names = re.findall(r"'([^']*)'", text)
            text = f"unknown ROS argument(s) {' '.join(names)}"
        return f"argument --ros-args: {text or 'invalid ROS arguments'}"
    return f"unrecognized arguments: {' '.join(rest)}" if rest else None


def _stop_on_signals() -> threading.Event:
    """An event that SIGINT and SIGTERM set (instead of raising or shutting rclpy down)."""
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    return stop


def spin_nodes(
    nodes: Sequence[Node],
    prog: str,
    duration_s: float | None = None,
    executor: Executor | None = None,
    stop: threading.Event | None = None,
    until: threading.Event | None = None,
    limit_s: float = SHUTDOWN_LIMIT_S,
    shutdown_timeout_s: float = 1.0,
) -> int:
    """Spin `nodes` until SIGINT/SIGTERM, `until` is set or `duration_s` passes; then stop them
    (see the module docstring). Needs rclpy initialised with SignalHandlerOptions.NO."""
    stop = stop or _stop_on_signals()
    _dump_stacks_on_fatal_signals()
    executor = executor or MultiThreadedExecutor(num_threads=8)
    if len(nodes) > 1:  # one /clock subscription for the process (see shared_clock)
        clock = SharedClock()
        for node in nodes:
            clock.join(node)
    for node in nodes:
        executor.add_node(node)
    failures: list[BaseException] = []
    leave = threading.Event()  # the spinner leaves its loop; only then is the executor shut down

    def spin() -> None:
        # Not executor.spin(): rclpy's Executor.shutdown() destroys the guard condition that a
        # spinning thread is putting in its wait set, so a shutdown under spin() raised
        # InvalidHandle or "'NoneType' object has no attribute 'handle'" there (exit 1 after a
        # clean stop, seen under load). spin_once in short slices ends the loop first.
        try:
            while not leave.is_set() and executor.context.ok():
                executor.spin_once(timeout_sec=SPIN_SLICE_S)
        except ExternalShutdownException:
            pass
        except Exception as exc:  # a bug in a callback: stop everything, exit 1
            failures.append(exc)
        finally:
            stop.set()

    spinner = threading.Thread(target=spin, name=f"{prog} executor", daemon=True)
    spinner.start()
    deadline = None if duration_s is None else time.monotonic() + duration_s
    while not stop.is_set() and not (until is not None and until.is_set()):
        left = 0.1 if deadline is None else min(0.1, deadline - time.monotonic())
        if left <= 0:
            break
        stop.wait(left)  # short waits: the main thread runs the signal handler between them
    watchdog = threading.Timer(limit_s, _give_up, args=(prog, limit_s))
    watchdog.daemon = True
    watchdog.start()
    dumps = _dump_stacks_later(limit_s + STACK_DUMP_GRACE_S)
    give_up_at = time.monotonic() + limit_s
    for node in nodes:
        node_stop = getattr(node, "stop", None)
        if callable(node_stop):
            try:
                node_stop()
            except Exception as exc:  # keep stopping the others
                print(f"{prog}: {node.get_name()}.stop(): {exc!r}", file=sys.stderr)
    # The spinner first leaves its loop, then the executor shuts down, then the nodes go: in
    # any other order a handle is destroyed under a thread that uses it. The watchdog bounds
    # the wait.
    leave.set()
    spinner.join(timeout=max(shutdown_timeout_s, give_up_at - time.monotonic()))
    executor.shutdown(timeout_sec=shutdown_timeout_s)
    for node in nodes:
        node.destroy_node()
    rclpy.try_shutdown()
    watchdog.cancel()
    if dumps:
        faulthandler.cancel_dump_traceback_later()
    if failures:
        print(f"{prog}: stopped by an error: {failures[0]!r}", file=sys.stderr)
        return EXIT_FAILURE
    return EXIT_OK


def _dump_stacks_on_fatal_signals() -> None:
    """faulthandler on the process's standard error (SIGABRT, SIGSEGV, ...: every thread's
    stack), unless it is on already (pytest turns it on for its own file)."""
    if not faulthandler.is_enabled():
        try:
            faulthandler.enable(file=sys.__stderr__)
        except (AttributeError, ValueError, OSError):  # no standard error with a descriptor
            pass


def _dump_stacks_later(seconds: float) -> bool:
    """faulthandler's watchdog: every thread's stack and exit 1 after `seconds`, even while a
    thread holds the GIL; whether it is armed (it needs a standard error with a descriptor)."""
    try:
        faulthandler.dump_traceback_later(seconds, exit=True, file=sys.__stderr__)
    except (AttributeError, ValueError, OSError):
        return False
    return True


def _give_up(prog: str, limit_s: float) -> None:
    busy = [t.name for t in threading.enumerate()
            if t is not threading.current_thread() and not t.daemon and t.is_alive()]
    print(f"{prog}: shutdown took over {limit_s} s (still busy: "
          f"{', '.join(busy) or 'callbacks'}); exiting", file=sys.stderr, flush=True)
    sys.stdout.flush()
    os._exit(EXIT_FAILURE)
