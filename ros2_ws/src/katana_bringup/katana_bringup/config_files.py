"""The packaged parameter files, generated from the nodes' parameter specs.

    python -m katana_bringup.config_files [--write]

config/graph.yaml, config/sim.yaml and katana_driver's config/hardware.yaml list every
parameter of their nodes with its description, so they are the reference a `--params` overlay
starts from; but a default is stated once, in its node's spec (`Param`), and these files are
written from the specs. The few deliberate values that differ from a default are in `FILES`
below, each with its reason. Without --write the command checks the files and names those that
differ (exit 1); test_bringup_config runs the same check. backend_sim.yaml and
backend_hardware.yaml hold only rclpy's use_sim_time and are written by hand.
"""

from __future__ import annotations

import sys
import textwrap
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

from katana_camera.camera_node import PARAMS as CAMERA_PARAMS
from katana_common.param_spec import Param, yaml_section
from katana_common.scene import SCENE_PARAMS
from katana_curiosity.node_params import PARAMS as CURIOSITY_PARAMS
from katana_description.frame_publisher import PARAMS as FRAME_PARAMS
from katana_driver.driver_params import PARAMS as DRIVER_PARAMS
from katana_manipulation.core.pick_place_types import SIM_MIN_SEGMENT_TIME_S
from katana_manipulation.pick_place_executor import PARAMS as EXECUTOR_PARAMS
from katana_manipulation.reach_params import REACH_PARAMS
from katana_perception.block_memory_node import PARAMS as MEMORY_PARAMS
from katana_perception.fovea_node import PARAMS as FOVEA_PARAMS
from katana_perception.perception_node import PARAMS as PERCEPTION_PARAMS
from katana_sim.sim_params import PARAMS as SIM_PARAMS

from . import generated

_SRC = Path(__file__).resolve().parents[2]
#: what graph.yaml sets once, under `/**`, for every node (the scene and the pick-and-place
#: geometry); no node's own section repeats them
GRAPH_WIDE: tuple[Param, ...] = (*SCENE_PARAMS, *REACH_PARAMS)
_GRAPH_WIDE_NAMES = {p.name for p in GRAPH_WIDE}


@dataclass(frozen=True)
class Section:
    node: str
    specs: tuple[Param, ...]
    values: Mapping[str, Any] = field(default_factory=dict)  # deliberate, not the default
    preface: str = ""  # a comment before the section


def _own(specs: Iterable[Param], only: Iterable[str] | None = None) -> tuple[Param, ...]:
    """A node's specs without the graph-wide ones (or only those named)."""
    if only is not None:
        names = set(only)
        return tuple(p for p in specs if p.name in names)
    return tuple(p for p in specs if p.name not in _GRAPH_WIDE_NAMES)


_GENERATED = ("Generated from the nodes' parameter specs by `python -m katana_bringup.config_files "
              "--write`: change a default in its spec, not here. A parameter marked live: `ros2 "
              "param set` applies it at once (validated as at start-up); every other one is "
              "read-only after start-up.")

FILES: dict[str, tuple[str, tuple[Section, ...]]] = {
    "graph.yaml": (
        "Parameters of the node graph above the arm (katana-run, launch/sim.launch.py), whatever "
        "the backend. Standard ROS 2 parameter YAML: node_name: ros__parameters: {...}; `/**` "
        "applies to every node. The backend's own file comes after this one (backend_sim.yaml + "
        "sim.yaml, or backend_hardware.yaml): it sets the clock and anything backend-specific. "
        + _GENERATED,
        (
            Section("/**", GRAPH_WIDE, preface=(
                "-- the scene and the pick-and-place geometry every node shares, set once and "
                "never under one node: the executor plans with approach_height and grasp_offset, "
                "and the nodes that offer placements compute the arm's reach from them")),
            Section("frame_publisher", _own(FRAME_PARAMS), preface=(
                "-- the frame tree (katana_description): /tf, /tf_static and robot_description, "
                "as robot_state_publisher publishes them, plus world -> arm base and the camera "
                "frames")),
            Section("pick_place_executor", _own(EXECUTOR_PARAMS), preface=(
                "-- pick and place (katana_manipulation)")),
            Section("perception_node", _own(PERCEPTION_PARAMS), preface=(
                "-- perception, block memory and fovea (katana_perception)")),
            Section("block_memory_node", _own(MEMORY_PARAMS)),
            Section("fovea_node", _own(FOVEA_PARAMS)),
            Section("curiosity_node", _own(CURIOSITY_PARAMS), preface=(
                "-- the curiosity learner and planner (katana_curiosity)")),
        ),
    ),
    "sim.yaml": (
        "Parameters of the simulation backend (katana-run --backend sim, launch/sim.launch.py), "
        "after graph.yaml (the scene under `/**`) and backend_sim.yaml (use_sim_time). "
        + _GENERATED,
        (
            Section("sim_node", _own(SIM_PARAMS)),
            Section("pick_place_executor", _own(EXECUTOR_PARAMS, only=["min_segment_time_s"]),
                    {"min_segment_time_s": SIM_MIN_SEGMENT_TIME_S}, preface=(
                        "-- the executor on the simulation: its controller follows any segment "
                        "length exactly (the default suits the real arm's driver, which merges "
                        "spline knots closer than that)")),
        ),
    ),
    "hardware.yaml": (
        "Hardware backend (backend:=hardware): the real Katana arm and the real overhead "
        "camera. Loaded by katana_driver.bringup.build_hardware_nodes and by "
        "launch/katana_hardware.launch.py (graph.yaml's `/**` comes after it); see "
        "docs/hardware.md. " + _GENERATED,
        (
            Section("katana_driver_node", _own(DRIVER_PARAMS)),
            Section("camera_node", _own(CAMERA_PARAMS)),
        ),
    ),
}


def _comment(text: str) -> str:
    return textwrap.fill(text, 99, initial_indent="# ", subsequent_indent="# ",
                         break_on_hyphens=False, break_long_words=False) + "\n"


def path_of(name: str) -> Path:
    """Where a generated file lives in the source tree."""
    package = "katana_driver" if name == "hardware.yaml" else "katana_bringup"
    return _SRC / package / "config" / name


def render(name: str) -> str:
    """The text of one generated file."""
    header, sections = FILES[name]
    parts = [_comment(header)]
    for section in sections:
        text = yaml_section(section.node, section.specs, section.values)
        parts.append((_comment(section.preface) if section.preface else "") + text)
    return "\n".join(parts)


def _files() -> dict[Path, Callable[[], str]]:
    return {path_of(name): partial(render, name) for name in FILES}


def stale() -> list[str]:
    """The generated files whose text differs from what the specs give."""
    return [path.name for path in generated.stale(_files())]


def main(argv: list[str] | None = None) -> int:
    return generated.write_or_check("python -m katana_bringup.config_files",
                                    __doc__.split("\n\n")[0], _files(), "its nodes' specs", argv)


if __name__ == "__main__":
    sys.exit(main())
