"""katana_driver_node's /diagnostics: the link, the set-up and the motors, from the worker's
state (katana_common.health; published by katana_common.diagnostics)."""

from __future__ import annotations

import statistics

from katana_common.health import ERROR, OK, WARN, Health

from .core import protocol as p
from .core.arm import ArmWorker

#: motor status values as KNI's header names their meaning
STATUS_NAMES = {
    p.STATUS_OFF: "off", p.STATUS_CALIBRATING: "calibrating", p.STATUS_HOLDING: "holding",
    p.STATUS_FOLLOWING: "moving", p.STATUS_MOVING: "moving",
    p.STATUS_COLLISION: "collision", p.STATUS_SPLINE_DONE: "spline done",
    p.STATUS_INVALID: "unknown", p.STATUS_BUFFER_FULL: "moving (buffer full)",
}


def driver_health(worker: ArmWorker, lifecycle: str = "active") -> Health:
    """ERROR without a link or after a set-up problem or a collision, WARN while connected but
    not ready (calibrating, waiting for the first poll) or not active (``lifecycle``, the
    node's lifecycle state: goals are refused), OK when goals can run."""
    stats = worker.transport.stats
    latencies = list(stats.latency_s)
    status = worker.state.status if worker.state is not None else []
    values: dict[str, object] = {
        "lifecycle_state": lifecycle,
        "connected": worker.connected,
        "calibrated": worker.calibrated,
        "master_version": ".".join(map(str, worker.master_version or ())) or "unknown",
        "polls": worker.polls,
        "link_losses": worker.link_losses,
        "replies": stats.replies,
        "retries": stats.retries,
        "timeouts": stats.timeouts,
        "crc_errors": stats.crc_errors,
        "reply_latency_median_ms": 1000.0 * statistics.median(latencies) if latencies else "none",
        "reply_latency_max_ms": 1000.0 * max(latencies) if latencies else "none",
    }
    for motor, value in enumerate(status, start=1):
        values[f"motor{motor}"] = STATUS_NAMES.get(value, f"status {value}")
    if not worker.connected:
        return Health(ERROR, f"no link to the controller: {worker.link_error}", values)
    if worker.setup_problem:
        return Health(ERROR, f"set-up stopped: {worker.setup_problem}", values)
    if worker.collision_message:
        return Health(ERROR, worker.collision_message, values)
    if lifecycle != "active":
        return Health(WARN, f"connected, {lifecycle}: goals are refused until it is active",
                      values)
    if not worker.ready:
        return Health(WARN, "connected, calibrating" if not worker.calibrated
                      else "connected, not ready yet", values)
    return Health(OK, "ready", values)
