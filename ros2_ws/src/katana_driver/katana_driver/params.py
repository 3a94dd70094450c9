"""Declaring validated ROS parameters: a bad value stops the node with a message naming it."""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import InvalidParameterValueException
from rclpy.node import Node


class ParameterError(ValueError):
    """A parameter value outside its valid range; the text names the parameter."""


def declare(
    node: Node,
    name: str,
    default: Any,
    description: str,
    low: float | None = None,
    high: float | None = None,
    choices: tuple | None = None,
) -> Any:
    """Declare ``name`` with a descriptor and return its value, checked."""
    descriptor = ParameterDescriptor(description=description)
    if low is not None and high is not None:
        if isinstance(default, bool) or not isinstance(default, (int, float)):
            raise TypeError(f"range given for non-numeric parameter '{name}'")
        if isinstance(default, int):
            descriptor.integer_range = [
                IntegerRange(from_value=int(low), to_value=int(high), step=0)
            ]
        else:
            descriptor.floating_point_range = [
                FloatingPointRange(from_value=float(low), to_value=float(high), step=0.0)
            ]
    if choices is not None:
        descriptor.additional_constraints = "one of: " + ", ".join(str(c) for c in choices)
    valid = _valid_text(low, high, choices)
    try:
        value = node.declare_parameter(name, default, descriptor).value
    except InvalidParameterValueException as exc:
        raise ParameterError(f"parameter '{name}': invalid value; valid: {valid}") from exc
    except Exception as exc:  # wrong type (e.g. a string for a number)
        raise ParameterError(f"parameter '{name}': {exc}; valid: {valid}") from exc
    if choices is not None and value not in choices:
        raise ParameterError(f"parameter '{name}' = {value!r} is not valid; valid: {valid}")
    if low is not None and high is not None and not low <= value <= high:
        raise ParameterError(f"parameter '{name}' = {value!r} is outside {valid}")
    return value


def _valid_text(low: float | None, high: float | None, choices: tuple | None) -> str:
    if choices is not None:
        return "one of " + ", ".join(repr(c) for c in choices)
    if low is not None and high is not None:
        return f"[{low}, {high}]"
    return "any value of the declared type"
