"""The `offered_qos_profiles` text of a rosbag2 channel (ROS-free: plain dicts, PyYAML).

rosbag2 on Jazzy (bag metadata version 9, rosbag2_storage's qos.cpp) stores, per topic, the
QoS profiles its publishers offered as a YAML sequence, each a block mapping in this order:

    - history: unknown
      depth: 0
      reliability: reliable
      durability: transient_local
      deadline:
        sec: 9223372036
        nsec: 854775807
      lifespan: {sec, nsec as above}
      liveliness: automatic
      liveliness_lease_duration: {sec, nsec as above}
      avoid_ros_namespace_conventions: false

Policies are rmw's short names (rmw_qos_*_to_str); durations are {sec, nsec}, with
RMW_DURATION_INFINITE (2^63 - 1 ns) as 9223372036 s 854775807 ns. `ros2 bag play` and
`rosbags` read it; playback offers what the recorded publishers offered, so a transient-local
topic stays transient local. Older bags wrote the policies as integers; `parse` takes both.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import yaml

INFINITE_NS = 2**63 - 1
HISTORY = ("system_default", "keep_last", "keep_all", "unknown")
RELIABILITY = ("system_default", "reliable", "best_effort", "unknown", "best_available")
DURABILITY = ("system_default", "transient_local", "volatile", "unknown", "best_available")
LIVELINESS = ("system_default", "automatic", "manual_by_topic", "unknown", "best_available")
#: the integer forms of metadata versions before 9 (rmw's enum values)
_LEGACY = {
    "history": dict(enumerate(HISTORY)),
    "reliability": dict(enumerate(RELIABILITY)),
    "durability": dict(enumerate(DURABILITY)),
    "liveliness": {0: "system_default", 1: "automatic", 3: "manual_by_topic", 4: "unknown",
                   5: "best_available"},
}
_POLICIES = {"history": HISTORY, "reliability": RELIABILITY, "durability": DURABILITY,
             "liveliness": LIVELINESS}
_DURATIONS = ("deadline", "lifespan", "liveliness_lease_duration")
#: what rosbag2 plays a topic with when the recording says nothing usable (rclcpp's default)
DEFAULT_DEPTH = 10


class QosFormatError(ValueError):
    """An offered_qos_profiles text that is not a sequence of QoS profiles."""


def profile(history: str = "keep_last", depth: int = DEFAULT_DEPTH,
            reliability: str = "reliable", durability: str = "volatile",
            deadline_ns: int = 0, lifespan_ns: int = 0, liveliness: str = "system_default",
            liveliness_lease_duration_ns: int = 0,
            avoid_ros_namespace_conventions: bool = False) -> dict[str, Any]:
    """One profile as a dict in rosbag2's key order (durations in nanoseconds)."""
    return {"history": history, "depth": depth, "reliability": reliability,
            "durability": durability, "deadline": _duration(deadline_ns),
            "lifespan": _duration(lifespan_ns), "liveliness": liveliness,
            "liveliness_lease_duration": _duration(liveliness_lease_duration_ns),
            "avoid_ros_namespace_conventions": bool(avoid_ros_namespace_conventions)}


def _duration(ns: int) -> dict[str, int]:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def duration_ns(value: Mapping[str, int]) -> int:
    return int(value["sec"]) * 1_000_000_000 + int(value["nsec"])


def dump(profiles: Sequence[Mapping[str, Any]]) -> str:
    """The YAML text rosbag2 writes (yaml-cpp's block style, no final newline; [] if none)."""
    if not profiles:
        return "[]"
    return yaml.safe_dump([dict(p) for p in profiles], sort_keys=False,
                          default_flow_style=False).rstrip("\n")


def parse(text: str) -> list[dict[str, Any]]:
    """The profiles of an offered_qos_profiles text, policies as short names ('' reads [])."""
    if not text.strip():
        return []
    try:
        items = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise QosFormatError(f"not YAML: {err}") from None
    if not isinstance(items, list):
        raise QosFormatError(f"expected a sequence of profiles, got {type(items).__name__}")
    return [_normalised(item) for item in items]


def _normalised(item: Any) -> dict[str, Any]:
    if not isinstance(item, dict):
        raise QosFormatError(f"a profile must be a mapping, got {item!r}")
    out: dict[str, Any] = {}
    try:
        for key, names in _POLICIES.items():
            value = item[key]
            if isinstance(value, bool) or not isinstance(value, int | str):
                raise QosFormatError(f"{key}: {value!r} is no policy")
            name = _LEGACY[key].get(value) if isinstance(value, int) else value.lower()
            if name not in names:
                raise QosFormatError(f"{key}: unknown policy {value!r}")
            out[key] = name
        depth = item["depth"]
        if isinstance(depth, bool) or not isinstance(depth, int) or depth < 0:
            raise QosFormatError(f"depth: {depth!r} is no count")
        out["depth"] = depth
        for key in _DURATIONS:
            value = item[key]
            if not (isinstance(value, dict) and all(
                    isinstance(value.get(k), int) and not isinstance(value.get(k), bool)
                    and value[k] >= 0 for k in ("sec", "nsec"))):
                raise QosFormatError(f"{key}: {value!r} is no {{sec, nsec}} duration")
            out[key] = {"sec": value["sec"], "nsec": value["nsec"]}
        out["avoid_ros_namespace_conventions"] = bool(item["avoid_ros_namespace_conventions"])
    except KeyError as err:
        raise QosFormatError(f"a profile without {err.args[0]!r}") from None
    return {k: out[k] for k in profile()}  # rosbag2's key order


def playback_profile(profiles: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """What to offer when playing a topic back (rosbag2's adapt_offer_to_recorded_offers):
    the recorded offer if every publisher offered the same compatibility policies, with the
    recorded history only where it is known (DDS discovery does not carry it), else rclcpp's
    default keep_last 10; the default reliable, volatile profile otherwise."""
    if not profiles:
        return profile()
    keys = ("reliability", "durability", "deadline", "liveliness", "liveliness_lease_duration")
    first = profiles[0]
    if any(any(p[k] != first[k] for k in keys) for p in profiles[1:]):
        return profile()
    out = {k: first[k] for k in profile()}
    if first["history"] not in ("keep_last", "keep_all") or (
            first["history"] == "keep_last" and first["depth"] == 0):
        out["history"], out["depth"] = "keep_last", DEFAULT_DEPTH
    for key, usable in (("reliability", ("reliable", "best_effort")),
                        ("durability", ("transient_local", "volatile"))):
        if out[key] not in usable:  # unknown or system_default: the default offer
            out[key] = profile()[key]
    return out
