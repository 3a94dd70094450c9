"""`run_node`: the one main() of every node (start-up errors, signals, shutdown, exit codes).

Exit codes, for every node and console tool of the project:
0 a clean stop (including SIGINT / SIGTERM), 1 a failure while running,
2 an invalid configuration (a parameter or argument outside its valid values; as argparse).

Shutdown order: rclpy's signal handler (SIGINT and SIGTERM) shuts the context down and the
executor's spin returns; the node's `stop()` (if it has one) ends its long waits and threads;
the executor is shut down; then the node is destroyed, so no callback runs on a destroyed node.
"""

from __future__ import annotations

from collections.abc import Callable

import rclpy
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from .params import ParameterError

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_INVALID_CONFIGURATION = 2


def run_node(
    make_node: Callable[[], Node],
    name: str,
    args: list[str] | None = None,
    executor_factory: Callable[[], Executor] = SingleThreadedExecutor,
    shutdown_timeout_s: float = 1.0,
) -> int:
    """Create the node, spin it until shutdown, tear it down; return the exit code."""
    rclpy.init(args=args)
    try:
        node = make_node()
    except ParameterError as err:
        rclpy.logging.get_logger(name).fatal(str(err))
        rclpy.try_shutdown()
        return EXIT_INVALID_CONFIGURATION
    executor = executor_factory()
    executor.add_node(node)
    code = EXIT_OK
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as err:  # a bug: say what, stop cleanly, exit non-zero
        node.get_logger().fatal(f"stopped by an error: {err!r}")
        code = EXIT_FAILURE
    finally:
        stop = getattr(node, "stop", None)
        if callable(stop):
            stop()
        executor.shutdown(timeout_sec=shutdown_timeout_s)
        node.destroy_node()
        rclpy.try_shutdown()
    return code
