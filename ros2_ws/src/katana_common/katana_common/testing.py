"""What tests that start node processes share: a ROS domain of their own."""

from __future__ import annotations

import os


def private_domain_id() -> int:
    """A ROS domain for this test process's node processes, distinct between the workers of one
    `pytest -n` run (PYTEST_XDIST_WORKER gwN), so that two tests never see each other's graph."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if worker.startswith("gw") and worker[2:].isdigit():
        return 120 + (int(worker[2:]) % 2) * 50 + os.getpid() % 45  # room for a few more
    return 120 + os.getpid() % 100


def private_ros_env(**extra: str) -> dict[str, str]:
    """os.environ with a private domain and localhost-only discovery, for a node subprocess."""
    return dict(os.environ, ROS_DOMAIN_ID=str(private_domain_id()),
                ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", **extra)
