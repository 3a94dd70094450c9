"""Declared, validated parameters: the one way every Katana node takes its configuration.

A node lists its parameters as `Param` specs and calls `declare_parameters` once. Each value is
checked against its spec at start-up (type, range, choices, list length, a cross-parameter rule),
and a bad one raises `ParameterError` naming the parameter and its valid values, which
`run_node` turns into a one-line fatal message and exit code 2. A YAML key the node does not
declare (a typo such as `alhpa`) is refused the same way instead of being ignored.

After start-up a parameter is either *live* (a `ros2 param set` is validated with the same spec
and, once accepted, handed to the node's `on_change` listeners) or *read-only* (refused by
rclpy with the descriptor's reason). Nothing is accepted that the node would not apply.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterException,
)
from rclpy.node import Node
from rclpy.parameter import Parameter

from .param_files import GRAPH_WIDE_GEOMETRY, TOLERATED_UNDECLARED
from .param_spec import Param

__all__ = ["Param", "ParameterError", "NodeParameters", "declare_parameters",
           "GRAPH_WIDE_GEOMETRY"]

class ParameterError(ValueError):
    """An invalid parameter; the message names it and its valid values."""


Listener = Callable[[dict[str, Any]], None]
CrossCheck = Callable[[Mapping[str, Any]], str | None]


class NodeParameters(Mapping):
    """The node's current, validated parameter values (read with `params["name"]`)."""

    def __init__(self, node: Node, specs: Iterable[Param], cross_check: CrossCheck | None) -> None:
        self._node = node
        self._specs = {s.name: s for s in specs}
        self._cross_check = cross_check
        self._values: dict[str, Any] = {}
        self._listeners: list[Listener] = []

    def __getitem__(self, name: str) -> Any:
        return self._values[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def spec(self, name: str) -> Param:
        return self._specs[name]

    def on_change(self, listener: Listener) -> None:
        """Call `listener({name: value, ...})` after a live change has been accepted and set."""
        self._listeners.append(listener)

    # -- start-up -------------------------------------------------------------------------
    def _declare_all(self) -> None:
        for spec in self._specs.values():
            self._values[spec.name] = self._declare(spec)
        self._refuse_unknown_overrides()
        self._check_cross(self._values)
        self._node.add_on_set_parameters_callback(self._validate_change)
        self._node.add_post_set_parameters_callback(self._apply_change)

    def _declare(self, spec: Param) -> Any:
        default = spec.default
        if isinstance(default, list) and not default:
            raise TypeError(f"parameter '{spec.name}': an empty list default has no type")
        try:
            value = self._node.declare_parameter(spec.name, default, spec.descriptor()).value
        except (
            InvalidParameterValueException,
            InvalidParameterTypeException,
            ParameterException,
        ) as exc:
            raise ParameterError(
                f"parameter '{spec.name}': {_first_line(exc)}; valid: {spec.valid_text()}"
            ) from exc
        if value is None:  # a YAML key without a value: rclpy passes it through as not set
            raise ParameterError(f"parameter '{spec.name}' has no value; valid: "
                                 f"{spec.valid_text()}")
        if isinstance(value, tuple | list) or type(value).__name__ == "array":
            value = list(value)
        reason = spec.problem(value)
        if reason:
            raise ParameterError(f"parameter '{spec.name}' {reason}; valid: {spec.valid_text()}")
        return value

    def _refuse_unknown_overrides(self) -> None:
        # rclpy keeps the YAML/--ros-args values for this node in _parameter_overrides and
        # ignores the ones never declared; there is no public accessor, so read it here.
        overrides = getattr(self._node, "_parameter_overrides", {}) or {}
        unknown = sorted(
            name
            for name in overrides
            if name not in self._specs
            and name not in TOLERATED_UNDECLARED  # (param_files: the same rule for files)
            and not name.startswith("qos_overrides.")
            and not self._node.has_parameter(name)
        )
        if unknown:
            raise ParameterError(
                f"unknown parameter {', '.join(repr(n) for n in unknown)} for node "
                f"'{self._node.get_name()}'; valid names: {', '.join(sorted(self._specs))}"
            )

    def _check_cross(self, values: Mapping[str, Any]) -> None:
        if self._cross_check is not None:
            reason = self._cross_check(values)
            if reason:
                raise ParameterError(reason)

    # -- run time -------------------------------------------------------------------------
    def _validate_change(self, parameters: list[Parameter]) -> SetParametersResult:
        candidate = dict(self._values)
        for parameter in parameters:
            spec = self._specs.get(parameter.name)
            if spec is None:
                continue  # rclpy's own (use_sim_time): rclpy validates those
            if not spec.live:
                return SetParametersResult(
                    successful=False,
                    reason=f"parameter '{spec.name}' is read-only: set it at start-up",
                )
            value = parameter.value
            if isinstance(value, tuple) or type(value).__name__ == "array":
                value = list(value)
            reason = spec.problem(value)
            if reason:
                return SetParametersResult(
                    successful=False,
                    reason=f"parameter '{spec.name}' {reason}; valid: {spec.valid_text()}",
                )
            candidate[spec.name] = value
        if self._cross_check is not None:
            reason = self._cross_check(candidate)
            if reason:
                return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _apply_change(self, parameters: list[Parameter]) -> None:
        changed = {}
        for parameter in parameters:
            if parameter.name not in self._specs:
                continue
            value = parameter.value
            if isinstance(value, tuple) or type(value).__name__ == "array":
                value = list(value)
            old = self._values.get(parameter.name)
            self._values[parameter.name] = value
            changed[parameter.name] = value
            self._node.get_logger().info(f"parameter {parameter.name}: {old!r} -> {value!r}")
        if changed:
            for listener in self._listeners:
                listener(changed)


def declare_parameters(
    node: Node, specs: Iterable[Param], cross_check: CrossCheck | None = None
) -> NodeParameters:
    """Declare every parameter of `node` (call once, with all of them) and return the values.

    Raises ParameterError for an invalid value or an unknown name in the node's overrides.
    `cross_check(values)` returns a reason when a combination is invalid (e.g. min >= max); it
    applies at start-up and to every live change.
    """
    params = NodeParameters(node, specs, cross_check)
    params._declare_all()
    return params


def _first_line(exc: Exception) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text.splitlines()[0]
