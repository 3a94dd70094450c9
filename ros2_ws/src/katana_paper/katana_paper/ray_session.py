"""The Ray session the paper's studies run on (the abstract sweeps and the robot runs): a local
Ray on loopback by default, a cluster by address; no usage statistics, no dashboard, no network
at run time."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager


def import_ray():
    """Ray, imported with its usage statistics off (Ray reads the setting when imported)."""
    os.environ["RAY_USAGE_STATS_ENABLED"] = "0"
    import ray  # noqa: PLC0415 - heavy, and only after the setting above

    return ray


@contextmanager
def ray_session(address: str | None, num_cpus: int) -> Iterator[object]:
    """This process's Ray session if there is one; otherwise a local Ray with `num_cpus` CPUs
    (address None) or a connection to the cluster at `address`, shut down on leaving."""
    ray = import_ray()
    started = not ray.is_initialized()
    if started:
        local = {} if address else {"_node_ip_address": "127.0.0.1"}
        ray.init(
            address=address or "local",
            num_cpus=None if address else num_cpus,
            # a local Ray binds to loopback and never looks up a route to the internet
            **local,
            include_dashboard=False,
            log_to_driver=False,
            configure_logging=True,
            logging_level="WARNING",
        )
    try:
        yield ray
    finally:
        if started:
            ray.shutdown()
