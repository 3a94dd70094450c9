"""`Param`: one parameter's name, default, description and valid values (no rclpy).

Kept apart from `params` so that shared parameter lists (`scene`) can be defined without rclpy.
`yaml_section` writes a node's specs as standard ROS 2 parameter YAML (the packaged files are
generated with it, so a default is stated once: in its spec).
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

Value = bool | int | float | str | list


@dataclass(frozen=True)
class Param:
    """One parameter: name, default, description and what values are valid.

    `low`/`high` bound a number or every element of a number list; `choices` lists the valid
    values of a scalar; `length` fixes a list's length (`min_length` bounds it below); `live`
    says whether the node applies a change at run time (otherwise it is read-only).
    """

    name: str
    default: Value
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple | None = None
    length: int | None = None
    min_length: int = 0
    nonempty: bool = False
    live: bool = False

    def valid_text(self) -> str:
        """The valid values in words, for messages and the descriptor."""
        parts = []
        if isinstance(self.default, list):
            if self.length is not None:
                parts.append(f"a list of {self.length}")
            elif self.min_length:
                parts.append(f"a list of at least {self.min_length}")
            else:
                parts.append("a list")
        if self.choices is not None:
            parts.append("one of " + ", ".join(repr(c) for c in self.choices))
        if self.low is not None or self.high is not None:
            lo = "-inf" if self.low is None else _number(self.low)
            hi = "inf" if self.high is None else _number(self.high)
            parts.append(f"in [{lo}, {hi}]")
        if self.nonempty:
            parts.append("not empty")
        if not parts:
            parts.append(f"any {type(self.default).__name__}")
        return ", ".join(parts)

    def problem(self, value: Any) -> str | None:
        """Why `value` is not valid for this parameter, or None when it is."""
        kind = type(self.default)
        if kind is bool:
            if not isinstance(value, bool):
                return f"must be true or false, got {value!r}"
            return None
        if kind is list:
            if not isinstance(value, list | tuple):
                return f"must be a list, got {value!r}"
            value = list(value)
            if self.length is not None and len(value) != self.length:
                return f"needs {self.length} values, got {len(value)}"
            if len(value) < self.min_length:
                return f"needs at least {self.min_length} values, got {len(value)}"
            for item in value:
                reason = self._scalar_problem(item)
                if reason:
                    return f"{value!r}: {reason}"
            return None
        return self._scalar_problem(value)

    def _scalar_problem(self, value: Any) -> str | None:
        if isinstance(value, bool) and not isinstance(self.default, bool):
            if not (
                isinstance(self.default, list)
                and self.default
                and isinstance(self.default[0], bool)
            ):
                return f"{value!r} is not a number or text"
        if isinstance(value, int | float) and not isinstance(value, bool):
            if not math.isfinite(value):
                return f"{value!r} is not finite"
            if self.low is not None and value < self.low:
                return f"{value!r} is below {_number(self.low)}"
            if self.high is not None and value > self.high:
                return f"{value!r} is above {_number(self.high)}"
        if isinstance(value, str) and self.nonempty and not value:
            return "must not be empty"
        if self.choices is not None and value not in self.choices:
            return f"{value!r} is not one of " + ", ".join(repr(c) for c in self.choices)
        return None

    def descriptor(self) -> ParameterDescriptor:
        desc = ParameterDescriptor(
            description=self.description,
            additional_constraints=self.valid_text(),
            read_only=not self.live,
        )
        numeric = self.default
        if isinstance(numeric, list):
            numeric = numeric[0] if numeric else None
        if self.low is not None and self.high is not None and not isinstance(self.default, list):
            if isinstance(numeric, int) and not isinstance(numeric, bool):
                desc.integer_range = [
                    IntegerRange(from_value=int(self.low), to_value=int(self.high), step=0)
                ]
            elif isinstance(numeric, float):
                desc.floating_point_range = [
                    FloatingPointRange(
                        from_value=float(self.low), to_value=float(self.high), step=0.0
                    )
                ]
        return desc


def _number(bound: float) -> str:
    """A bound as people write it: 2147483647 and 10000000 whole, 0.001 short."""
    if float(bound).is_integer() and abs(bound) < 1e16:
        return str(int(bound))
    return f"{bound:g}"


_WIDTH = 99


def yaml_value(value: Value) -> str:
    """`value` as a YAML flow scalar or sequence that both PyYAML and rcl read back with its
    type (a float always with a '.', so that 1.0 stays a double)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        text = repr(value)
        if "e" in text and "." not in text:
            mantissa, exponent = text.split("e")
            text = f"{mantissa}.0e{exponent}"
        return text if ("." in text or "e" in text) else text + ".0"
    if isinstance(value, str):
        return _quoted(value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(yaml_value(v) for v in value) + "]"
    raise TypeError(f"no YAML for {value!r}")


def _quoted(text: str) -> str:
    """A YAML double-quoted scalar: printable ASCII as it is, everything else escaped."""
    out = []
    for char in text:
        code = ord(char)
        if char in '"\\':
            out.append("\\" + char)
        elif 0x20 <= code < 0x7F:
            out.append(char)
        elif code <= 0xFF:
            out.append(f"\\x{code:02x}")
        elif code <= 0xFFFF:
            out.append(f"\\u{code:04x}")
        else:
            out.append(f"\\U{code:08x}")
    return '"' + "".join(out) + '"'


def _entry(spec: Param, value: Value, indent: str) -> list[str]:
    note = spec.description
    if spec.live and "live" not in note:
        note = "[live] " + note
    if value != spec.default:
        note += f" (default {yaml_value(spec.default)})"
    lines = textwrap.wrap(note, _WIDTH - len(indent) - 2, break_on_hyphens=False)
    out = [f"{indent}# {line}" for line in lines]
    text = f"{indent}{spec.name}: {yaml_value(value)}"
    if len(text) > _WIDTH and isinstance(value, list | tuple) and len(value) > 1:
        lead = " " * (len(indent) + len(spec.name) + 3)
        items = [yaml_value(v) for v in value]
        text = f"{indent}{spec.name}: [{items[0]}"
        for item in items[1:]:
            if len(text) + len(item) + 3 > _WIDTH:
                out.append(text + ",")
                text = lead + item
            else:
                text += ", " + item
        text += "]"
    out.append(text)
    return out


def yaml_section(node: str, specs: Iterable[Param],
                 values: Mapping[str, Value] | None = None) -> str:
    """`node: {ros__parameters: ...}` with every spec's default, or its entry in `values` (a
    deliberate choice, noted with the default), each under its description."""
    values = dict(values or {})
    specs = list(specs)
    unknown = sorted(set(values) - {s.name for s in specs})
    if unknown:
        raise ValueError(f"{node}: no spec for {', '.join(unknown)}")
    lines = [f"{node}:", "  ros__parameters:"]
    for spec in specs:
        value = values.get(spec.name, spec.default)
        reason = spec.problem(value)
        if reason:
            raise ValueError(f"{node}: parameter '{spec.name}' {reason}")
        lines += _entry(spec, value, "    ")
    return "\n".join(lines) + "\n"
