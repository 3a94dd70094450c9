"""`Param`: one parameter's name, default, description and valid values (no rclpy).

Kept apart from `params` so that shared parameter lists (`scene`) can be defined without rclpy.
"""

from __future__ import annotations

import math
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
            lo = "-inf" if self.low is None else f"{self.low:g}"
            hi = "inf" if self.high is None else f"{self.high:g}"
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
                return f"{value!r} is below {self.low:g}"
            if self.high is not None and value > self.high:
                return f"{value!r} is above {self.high:g}"
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
