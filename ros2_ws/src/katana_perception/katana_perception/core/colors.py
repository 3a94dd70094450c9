"""The colour table: one entry per block colour, as hue intervals on OpenCV's 0..179 scale.

Hue survives shading (a shaded face keeps its hue and saturation, only its value drops), so
a hue interval plus global saturation/value floors segments matte blocks on a grey table.
Entries are tunable as strings "name:lo-hi[,lo-hi]" (a ROS string-array parameter).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class ColorRange:
    name: str
    hues: tuple[tuple[int, int], ...]  # inclusive intervals on 0..179

    def __post_init__(self) -> None:
        if not self.name or any(c in self.name for c in ":, "):
            raise ValueError(f"colour name {self.name!r} must be non-empty without ':', ',', ' '")
        if not self.hues:
            raise ValueError(f"colour {self.name!r} has no hue interval")
        for lo, hi in self.hues:
            if not (0 <= lo <= hi <= 179):
                raise ValueError(f"colour {self.name!r}: hue interval {lo}-{hi} not in 0..179")

    def to_string(self) -> str:
        return self.name + ":" + ",".join(f"{lo}-{hi}" for lo, hi in self.hues)


# Defaults for matte block colours under white light (hue of the nominal RGB in
# NOMINAL_RGB below +- half the gap to the neighbours). Order = block id order.
DEFAULT_COLOR_TABLE: tuple[ColorRange, ...] = (
    ColorRange("red", ((0, 7), (172, 179))),
    ColorRange("green", ((41, 80),)),
    ColorRange("blue", ((103, 127),)),
    ColorRange("yellow", ((21, 40),)),
    ColorRange("orange", ((8, 20),)),
    ColorRange("purple", ((128, 147),)),
    ColorRange("cyan", ((81, 102),)),
    ColorRange("magenta", ((148, 171),)),
)

# Nominal matte colours (RGB 0..1), used by the synthetic renderer in tests and benchmarks.
NOMINAL_RGB: dict[str, tuple[float, float, float]] = {
    "red": (0.85, 0.10, 0.10),
    "green": (0.10, 0.70, 0.20),
    "blue": (0.10, 0.25, 0.85),
    "yellow": (0.95, 0.85, 0.10),
    "orange": (1.00, 0.50, 0.00),
    "purple": (0.50, 0.15, 0.75),
    "cyan": (0.00, 0.75, 0.80),
    "magenta": (0.90, 0.10, 0.70),
}


def parse_color_entry(entry: str) -> ColorRange:
    """'red:0-7,172-179' -> ColorRange; raises ValueError with the offending text."""
    try:
        name, spec = entry.strip().split(":", 1)
        hues = []
        for part in spec.split(","):
            lo, hi = part.strip().split("-", 1)
            hues.append((int(lo), int(hi)))
    except ValueError as err:
        raise ValueError(f"colour entry {entry!r} is not 'name:lo-hi[,lo-hi]' ({err})") from err
    return ColorRange(name.strip(), tuple(hues))


def parse_color_table(entries: Iterable[str]) -> tuple[ColorRange, ...]:
    table = tuple(parse_color_entry(e) for e in entries)
    if not table:
        raise ValueError("the colour table is empty")
    names = [c.name for c in table]
    if len(set(names)) != len(names):
        raise ValueError(f"colour names must be unique: {names}")
    return table


def color_table_strings(table: Sequence[ColorRange] = DEFAULT_COLOR_TABLE) -> list[str]:
    return [c.to_string() for c in table]
