"""Declaring validated parameters (the team's rule: invalid values stop the node at start-up,
naming the parameter and its valid range)."""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Sequence

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from .core.calibration import DEFAULT_CAMERA_POSITION, DEFAULT_CAMERA_RPY


class ParameterError(ValueError):
    """An invalid parameter; the message names it and its valid range."""


def declare(node: Node, name: str, default, description: str,
            lo: float | None = None, hi: float | None = None):
    """Declare one parameter with a description (and range for scalars); return its value."""
    desc = ParameterDescriptor(description=description)
    if lo is not None and hi is not None:
        if isinstance(default, bool):
            pass
        elif isinstance(default, int):
            desc.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
        elif isinstance(default, float):
            desc.floating_point_range = [
                FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)
            ]
    try:
        value = node.declare_parameter(name, default, desc).value
    except (InvalidParameterValueException, InvalidParameterTypeException) as err:
        valid = f" (valid: {lo}..{hi})" if lo is not None else ""
        raise ParameterError(f"parameter '{name}': {err}{valid}") from err
    if isinstance(default, list) and lo is not None and hi is not None:
        for v in value:
            if not (isinstance(v, int | float) and math.isfinite(v) and lo <= v <= hi):
                raise ParameterError(f"parameter '{name}': {list(value)} has a value outside "
                                     f"{lo}..{hi}")
    return value


def require_length(name: str, value: Sequence, n: int) -> list:
    if len(value) != n:
        raise ParameterError(f"parameter '{name}': needs {n} numbers, got {list(value)}")
    return list(value)


def declare_scene(node: Node) -> dict:
    """Parameters every perception node shares: frame, block size and camera pose."""
    out = {
        "world_frame": declare(node, "world_frame", "world", "Frame of every published pose."),
        "block_size": require_length("block_size", declare(
            node, "block_size", [0.04, 0.04, 0.03],
            "Block edge lengths x, y, z in metres (each 0.005..0.2).", 0.005, 0.2), 3),
        "camera_position": require_length("camera_position", declare(
            node, "camera_position", list(DEFAULT_CAMERA_POSITION),
            "Optical centre of the overhead camera in the world frame, m (-10..10).",
            -10.0, 10.0), 3),
        "camera_rpy": require_length("camera_rpy", declare(
            node, "camera_rpy", [float(a) for a in DEFAULT_CAMERA_RPY],
            "Roll, pitch, yaw (fixed axes) of camera_optical_frame in the world frame, rad "
            "(-2pi..2pi).", -2 * math.pi, 2 * math.pi), 3),
        "extrinsics_file": declare(
            node, "extrinsics_file", "",
            "Extrinsics YAML written by katana-calibrate; when set it replaces camera_position "
            "and camera_rpy."),
    }
    if not out["world_frame"]:
        raise ParameterError("parameter 'world_frame': must not be empty")
    if out["extrinsics_file"]:
        from pathlib import Path

        if not Path(out["extrinsics_file"]).is_file():
            raise ParameterError(f"parameter 'extrinsics_file': no such file "
                                 f"{out['extrinsics_file']!r}")
    return out


#: world/blocks and other state topics: the latest value, kept for late subscribers
STATE_QOS = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                       reliability=ReliabilityPolicy.RELIABLE)


def run_node(make_node: Callable[[], Node], name: str, executor_type: type[Executor],
             args: list[str] | None = None) -> None:
    """The nodes' main(): an invalid parameter stops start-up with its message and exit 1."""
    rclpy.init(args=args)
    try:
        node = make_node()
    except (ParameterError, ValueError) as err:
        rclpy.logging.get_logger(name).fatal(str(err))
        rclpy.try_shutdown()
        sys.exit(1)
    executor = executor_type()
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
