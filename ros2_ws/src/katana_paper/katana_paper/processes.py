"""The start method of the paper's worker processes (runs, figures): a fork server, not fork.

Forking copies only the calling thread, with every object of the others in whatever state it
was in. From a process that had hosted ROS nodes (a pytest worker that ran ROS tests; any
program that uses the paper's functions beside rclpy) a forked figure worker died of a
segmentation fault while collecting garbage in matplotlib. Workers started by a fork server
begin from a clean interpreter: what they need is pickled to them (configs, results)."""

from __future__ import annotations

import multiprocessing
from multiprocessing.context import BaseContext

#: imported once by the fork server, so that every worker it forks starts with them loaded
PRELOAD = ("katana_paper.experiments", "katana_paper.figures")


def worker_context() -> BaseContext:
    """forkserver where the platform has one (Linux, macOS), else spawn."""
    methods = multiprocessing.get_all_start_methods()
    if "forkserver" not in methods:
        return multiprocessing.get_context("spawn")
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(list(PRELOAD))  # no effect once the server runs
    return context
