"""The node graph's parameters checked before any node exists (katana-run, katana-demo).

Each node of the graph is listed with its parameter specs and its cross-parameter rule, the
ones it applies at start-up, so that `check_graph` (katana_common.param_files) refuses a bad
`--params` file, a bad `--ros-args -p` or `--params-file`, or a bad value an option sets, with
the file, the line and the key, before a folder is made or a node built. A section for a node
of the graph that is not started (another layer) has its own names and values checked too.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml
from katana_camera.camera_node import PARAMS as CAMERA_PARAMS
from katana_common.cli_args import CommandLineError
from katana_common.node_runner import ros_args_problem
from katana_common.param_files import (
    WILDCARD,
    Entry,
    ParamFileError,
    ParamSet,
    check_node,
    check_sections,
    read_param_files,
)
from katana_common.param_spec import Param
from katana_curiosity.node_params import PARAMS as CURIOSITY_PARAMS
from katana_curiosity.node_params import cross_check as curiosity_rule
from katana_description.frame_publisher import PARAMS as FRAME_PARAMS
from katana_description.frame_publisher import cross_check as frame_rule
from katana_driver.driver_params import PARAMS as DRIVER_PARAMS
from katana_driver.driver_params import cross_check as driver_rule
from katana_manipulation.pick_place_executor import PARAMS as EXECUTOR_PARAMS
from katana_manipulation.pick_place_executor import cross_check as executor_rule
from katana_perception.block_memory_node import PARAMS as MEMORY_PARAMS
from katana_perception.fovea_node import PARAMS as FOVEA_PARAMS
from katana_perception.fovea_node import cross_check as fovea_rule
from katana_perception.perception_node import PARAMS as PERCEPTION_PARAMS
from katana_perception.perception_params import check_files_and_colors
from katana_sim.sim_params import PARAMS as SIM_PARAMS
from katana_sim.sim_params import cross_check as sim_rule
from katana_sim.sim_params import sim_config

from .foxglove_bridge import NAME as FOXGLOVE_BRIDGE
from .foxglove_bridge import PARAMS as FOXGLOVE_PARAMS
from .recorder_node import PARAMS as RECORDER_PARAMS

BACKENDS = ("sim", "hardware")
LAYERS = ("arm", "perception", "curiosity")
#: the nodes each backend starts in the arm layer (a YAML section for another name is a typo)
NODE_NAMES = {
    "sim": ("sim_node",),
    "hardware": ("katana_driver_node", "camera_node"),
}
#: the nodes above the arm, whatever the backend, the recorder and the Foxglove bridge (its
#: section is checked; --foxglove gives it the host and port)
GRAPH_NODES = ("frame_publisher", "pick_place_executor", "perception_node", "block_memory_node",
               "fovea_node", "curiosity_node", "run_recorder", FOXGLOVE_BRIDGE)
_LAYER_NODES = {"arm": ("frame_publisher", "pick_place_executor"),
                "perception": ("perception_node", "block_memory_node", "fovea_node"),
                "curiosity": ("curiosity_node",)}
RECORDER = "run_recorder"

Rule = Callable[[Mapping[str, Any]], "str | None"]


def _sim_rule(values: Mapping[str, Any]) -> str | None:
    """sim_node's cross-check, then what its SimConfig refuses (ConfigError, a ValueError)."""
    reason = sim_rule(values)
    if reason is None:
        sim_config(values)
    return reason


#: node name -> (its parameter specs, its cross-parameter rule): what the node checks at start-up
NODE_RULES: dict[str, tuple[Sequence[Param], Rule | None]] = {
    "sim_node": (SIM_PARAMS, _sim_rule),
    "katana_driver_node": (DRIVER_PARAMS, driver_rule),
    "camera_node": (CAMERA_PARAMS, None),
    "frame_publisher": (FRAME_PARAMS, frame_rule),
    "pick_place_executor": (EXECUTOR_PARAMS, executor_rule),
    "perception_node": (PERCEPTION_PARAMS, check_files_and_colors),
    "block_memory_node": (MEMORY_PARAMS, check_files_and_colors),
    "fovea_node": (FOVEA_PARAMS, fovea_rule),
    "curiosity_node": (CURIOSITY_PARAMS, curiosity_rule),
    RECORDER: (RECORDER_PARAMS, None),
    FOXGLOVE_BRIDGE: (FOXGLOVE_PARAMS, None),
}


def graph_node_names(backend: str) -> tuple[str, ...]:
    """Every node a graph of this backend may start (the valid YAML sections besides `/**`)."""
    return (*NODE_NAMES[backend], *GRAPH_NODES)


def started_nodes(backend: str, layers: Iterable[str] = LAYERS, record: bool = False) -> list[str]:
    """The nodes katana_bringup.run.build_nodes starts for these layers."""
    layers = set(layers)
    names = [*NODE_NAMES[backend]] if "arm" in layers else []
    names += [n for layer in LAYERS if layer in layers for n in _LAYER_NODES[layer]]
    return names + ([RECORDER] if record else [])


def check_graph(params: ParamSet, backend: str, layers: Iterable[str] = LAYERS,
                record: bool = False, base: Mapping[str, Mapping[str, Entry]] | None = None,
                ) -> None:
    """Every section names a node of the graph, and every node is given what it accepts
    (ParamFileError otherwise). `base` holds a backend's own file, below the wildcard."""
    check_sections(params, graph_node_names(backend), f"the {backend} graph")
    started = started_nodes(backend, layers, record)
    for node in graph_node_names(backend):
        specs, rule = NODE_RULES[node]
        if node in started:
            check_node(params, node, specs, rule, (base or {}).get(node))
        elif node in params.sections:
            check_node(params, node, specs, started=False)
    check_agreement(params, started, base)


#: parameters that name one fact about the whole graph: every started node declaring one must be
#: given the same value (a sim of one Katana type under an executor planning for another would
#: move the arm the executor did not plan for)
SHARED_PARAMS = ("model", "camera_frame", "extrinsics_file", "world_frame")
#: (node, shared name) -> the name that node declares it by
SHARED_ALIASES = {("camera_node", "camera_frame"): "frame_id"}


def shared_name(node: str, name: str) -> str | None:
    """The name under which `node` declares the shared parameter `name`, or None."""
    own = SHARED_ALIASES.get((node, name), name)
    return own if any(p.name == own for p in NODE_RULES[node][0]) else None


def check_agreement(params: ParamSet, started: Iterable[str],
                    base: Mapping[str, Mapping[str, Entry]] | None = None) -> None:
    """Every started node that declares a SHARED_PARAMS name gets one value for it, its
    default counted where it is given none (ParamFileError naming the nodes otherwise)."""
    for name in SHARED_PARAMS:
        # value -> (node, its entry if given, whether given on top of the packaged files)
        groups: dict[Any, list[tuple[str, Entry | None, bool]]] = {}
        for node in started:
            own = shared_name(node, name)
            if own is None:
                continue
            packaged = (base or {}).get(node, {}).get(own)
            entry = {**(base or {}).get(node, {}), **params.overrides(node)}.get(own)
            default = next(p.default for p in NODE_RULES[node][0] if p.name == own)
            value = default if entry is None else entry.value
            groups.setdefault(_hashable(value), []).append(
                (node, entry, entry is not None and entry is not packaged))
        if len(groups) > 1:
            said = "; ".join(f"{', '.join(_named(n, name) for n, _, _ in nodes)}: {value!r}"
                             for value, nodes in groups.items())
            # blamed: the value given on top of the packaged files to the fewest nodes
            blamed = min(groups.values(), key=lambda g: (not any(on for *_, on in g), len(g)))
            given = [e for _, e, on in blamed if on] or [e for _, e, _ in blamed if e]
            entry = _last_filed(given) or Entry(None, "--params")
            raise ParamFileError(entry.where, f"parameter '{name}' must be the same for every "
                                 f"node of the graph that declares it; given {said}",
                                 entry.option)


def _named(node: str, name: str) -> str:
    own = shared_name(node, name)
    return node if own == name else f"{node} ({own})"


def _hashable(value: Any) -> Any:
    return tuple(value) if isinstance(value, list) else value


def _last_filed(entries: Sequence[Entry]) -> Entry | None:
    filed = [e for e in entries if e.where]
    return filed[-1] if filed else (entries[-1] if entries else None)


def hardware_base(backend: str) -> dict[str, dict[str, Entry]]:
    """For the hardware backend, katana_driver's hardware.yaml (what build_hardware_nodes puts
    below the graph's entries); nothing for the sim."""
    if backend != "hardware":
        return {}
    try:
        from katana_driver.bringup import default_config_path  # noqa: PLC0415 - only if chosen
    except ImportError:
        return {}  # build_nodes says that the backend is not available
    return read_param_files([Path(default_config_path())], option="--backend").sections


def add_ros_args(params: ParamSet, ros_args: Sequence[str]) -> None:
    """Check ROS arguments as rclpy.init will parse them and add their parameters: each
    `-p [node:]name:=value` and each `--params-file F`. A `-p` without a node name is every
    node's: it replaces the name in every section read before it, as a node's own entry would
    otherwise win over the wildcard. Raises CommandLineError naming --ros-args."""
    if not ros_args:
        return
    problem = ros_args_problem(["prog", *ros_args])
    if problem:
        raise CommandLineError("--ros-args", problem.removeprefix("argument --ros-args: "))
    for flag, value in zip(ros_args, ros_args[1:], strict=False):
        if flag in ("-p", "--param"):
            name, _, text = value.partition(":=")
            node, _, name = name.rpartition(":")
            try:
                parsed = yaml.safe_load(text)
            except yaml.YAMLError as err:
                raise CommandLineError("--ros-args", f"-p {value}: not a YAML value: "
                                       f"{' '.join(str(err).split())}") from None
            for section in ([node] if node else [WILDCARD, *(
                    n for n, entries in params.sections.items()
                    if n != WILDCARD and name in entries)]):
                params.set(section, name, parsed, "--ros-args", f"-p {value}")
        elif flag == "--params-file":
            params.read(value, "--ros-args")


def refusal(err: ParamFileError) -> CommandLineError:
    """A parameter refusal as a command-line one, naming the option that brought it in."""
    return CommandLineError(err.option, str(err))
