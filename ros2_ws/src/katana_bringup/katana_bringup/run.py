"""katana-run: the whole node graph in one process (for machines without ros2 launch).

    katana-run [--backend sim|hardware] [--params FILE ...] [--duration S] [--record F.mcap]
               [--foxglove [PORT]] [--foxglove-host HOST] [--ros-args ...]

Loads standard ROS parameter YAML files (`node_name: {ros__parameters: {...}}`, with `/**` for
every node): the packaged ones (config/graph.yaml, then the backend's: backend_sim.yaml and
sim.yaml, or backend_hardware.yaml), overlaid by each `--params FILE` in order, then by the
parameters of `--ros-args` (`-p [node:]name:=value`, `--params-file F`). Each node gets
its parameters as overrides, and every node spins on one MultiThreadedExecutor. Every option,
every `--params` file and the parameters of `--ros-args` are checked before any node is built,
by the rules the nodes apply (graph_params): a section of no node, an undeclared name, a value
of the wrong type or outside its spec is refused naming the file, the line and the key.
launch/sim.launch.py starts the same nodes, with the same YAML, as separate processes for
users with a full ROS 2 install. `--record F.mcap` adds a recorder of the run's topics (rosbag2
MCAP; katana_bringup.recorder_node). `--foxglove [PORT]` adds a live view for the Foxglove app
(a WebSocket server on 127.0.0.1:8765 by default; katana_bringup.foxglove_bridge).

The graph has three layers: "arm" (the backend's arm and camera nodes, the frame publisher
and the pick-and-place executor), "perception" (perception, block memory and fovea nodes) and
"curiosity" (the learner). `--layers` starts a subset, e.g. only the arm for a manipulation check.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import rclpy
from ament_index_python.packages import get_package_share_directory
from katana_common.cli_args import (
    CommandLineError,
    comma_list,
    listen_host,
    new_file,
    parse_command_line,
    positive_seconds,
    readable_file,
    tcp_port,
)
from katana_common.executor import MultiThreadedExecutor
from katana_common.node_runner import EXIT_INVALID_CONFIGURATION, spin_nodes
from katana_common.param_files import ParamFileError, ParamSet, read_param_files
from katana_common.params import ParameterError
from katana_curiosity.curiosity_node import CuriosityNode
from katana_description.frame_publisher import FramePublisher
from katana_manipulation.pick_place_executor import PickPlaceExecutor
from katana_perception.block_memory_node import BlockMemoryNode
from katana_perception.fovea_node import FoveaNode
from katana_perception.perception_node import PerceptionNode
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions

from .foxglove_bridge import NAME as FOXGLOVE_BRIDGE
from .foxglove_bridge import FoxgloveBridgeNode
from .graph_params import (
    BACKENDS,
    LAYERS,
    add_ros_args,
    check_graph,
    hardware_base,
    refusal,
)
from .live_view import add_foxglove_arguments, foxglove_address
from .recorder_node import RecorderNode

PACKAGE = "katana_bringup"
#: threads of the shared executor: action callbacks that wait on other actions each hold one
EXECUTOR_THREADS = 8
#: longest wait for the whole graph's threads after a stop request, s (katana-run ends in 3 s)
KATANA_RUN_SHUTDOWN_LIMIT_S = 2.5


def config_dir() -> Path:
    """The installed config folder (ament index) or the source tree's."""
    try:
        path = Path(get_package_share_directory(PACKAGE)) / "config"
        if path.is_dir():
            return path
    except Exception:  # not installed: fall back to the source tree
        pass
    return Path(__file__).resolve().parent.parent / "config"


def default_params_files(backend: str = "sim") -> list[Path]:
    """graph.yaml (the nodes above the arm, the scene under `/**`), then the backend's own:
    backend_<name>.yaml (its clock) and, for the sim, sim.yaml; the hardware nodes read
    katana_driver's hardware.yaml themselves (overlaid by these files' sections for them)."""
    files = [config_dir() / "graph.yaml", config_dir() / f"backend_{backend}.yaml"]
    if backend == "sim":
        files.append(config_dir() / "sim.yaml")
    return files


def load_params(paths: list[str | Path]) -> dict[str, dict[str, Any]]:
    """Merge ROS parameter YAML files into {node_name: {param: value}}; later files win.
    The wildcard entry `/**` (or `**`) applies to every node and is kept under '/**'; nested
    mappings become dotted names. A file that is not parameter YAML raises ParamFileError (a
    ValueError) naming the file and the line."""
    return read_param_files(paths).values()


def overrides_for(node_name: str, params: dict[str, dict[str, Any]]) -> list:
    """rclpy Parameters for one node: the wildcard entries, then the node's own."""
    values = {**params.get("/**", {}), **params.get(node_name, {})}
    return [Parameter(name, value=value) for name, value in values.items()]


def _sim_nodes(params: dict, context) -> list:
    from katana_sim.sim_node import SimNode  # noqa: PLC0415 - a backend's package loads only when chosen

    return [SimNode(context=context, parameter_overrides=overrides_for("sim_node", params))]


def _hardware_nodes(params: dict, context) -> list:
    try:
        from katana_driver.bringup import CAMERA, DRIVER, build_hardware_nodes  # noqa: PLC0415 - only if chosen
    except ImportError as exc:
        raise SystemExit(
            "katana-run: backend 'hardware' needs katana_driver (katana_driver.bringup."
            f"build_hardware_nodes), which is not available: {exc}"
        ) from None
    wildcard = params.get("/**", {})  # the clock and the scene, as for every other node
    own = {name: {**wildcard, **params.get(name, {})} for name in (DRIVER, CAMERA)}
    return list(build_hardware_nodes(own, context))


#: backend name -> builder of the nodes that stand for the arm and the camera
BACKEND_BUILDERS: dict[str, Callable[[dict, Any], list]] = {
    "sim": _sim_nodes,
    "hardware": _hardware_nodes,
}


def _perception_nodes(params: dict, context) -> list:
    return [
        cls(context=context, parameter_overrides=overrides_for(name, params))
        for cls, name in ((PerceptionNode, "perception_node"),
                          (BlockMemoryNode, "block_memory_node"), (FoveaNode, "fovea_node"))
    ]


def _curiosity_nodes(params: dict, context) -> list:
    return [CuriosityNode(context=context,
                          parameter_overrides=overrides_for("curiosity_node", params))]


def build_nodes(
    backend: str,
    params: dict[str, dict[str, Any]],
    context=None,
    layers: tuple[str, ...] | list[str] = LAYERS,
    record: str | Path | None = None,
    foxglove: tuple[str, int] | None = None,
) -> list:
    """Every node of the chosen layers of the graph for a backend, constructed in `context`,
    plus the run recorder when `record` names an MCAP file and the Foxglove bridge when
    `foxglove` gives its (host, port).

    Nodes whose construction fails (an invalid parameter) raise; nodes built before are
    destroyed first so nothing is left half running."""
    if backend not in BACKEND_BUILDERS:
        raise ValueError(f"backend '{backend}' is unknown; use one of {list(BACKEND_BUILDERS)}")
    unknown = [layer for layer in layers if layer not in LAYERS]
    if unknown:
        raise ValueError(f"unknown layer(s) {unknown}; use some of {list(LAYERS)}")

    nodes: list = []
    try:
        if "arm" in layers:
            nodes += BACKEND_BUILDERS[backend](params, context)
            nodes.append(FramePublisher(
                context=context, parameter_overrides=overrides_for("frame_publisher", params)))
            nodes.append(PickPlaceExecutor(
                context=context,
                parameter_overrides=overrides_for("pick_place_executor", params)))
        if "perception" in layers:
            nodes += _perception_nodes(params, context)
        if "curiosity" in layers:
            nodes += _curiosity_nodes(params, context)
        if record is not None:
            own = {**params, "run_recorder": {**params.get("run_recorder", {}),
                                              "path": str(record)}}
            nodes.append(RecorderNode(context=context,
                                      parameter_overrides=overrides_for("run_recorder", own)))
        if foxglove is not None:
            host, port = foxglove
            own = {**params, FOXGLOVE_BRIDGE: {**params.get(FOXGLOVE_BRIDGE, {}),
                                               "host": host, "port": port}}
            nodes.append(FoxgloveBridgeNode(
                context=context, parameter_overrides=overrides_for(FOXGLOVE_BRIDGE, own)))
    except BaseException:
        for node in nodes:
            node.destroy_node()
        raise
    return nodes


_layer_names = comma_list(LAYERS, "layer")


def _layers(text: str) -> list[str]:
    return [x.strip() for x in _layer_names(text).split(",") if x.strip()]


def add_graph_arguments(parser: argparse.ArgumentParser) -> None:
    """The options katana-run and katana-demo share (each validated while parsing; the
    --params files by `graph_params_check`, once the backend is known)."""
    parser.add_argument("--backend", choices=BACKENDS, default="sim")
    parser.add_argument("--params", action="append", default=[], metavar="FILE",
                        type=readable_file,
                        help="ROS parameter YAML overlaid on the packaged config (repeatable; "
                        "later files win)")
    parser.add_argument("--record", type=new_file(".mcap"), default=None, metavar="FILE.mcap",
                        help="record the run's topics into a rosbag2 MCAP file (in an existing "
                        "folder)")
    add_foxglove_arguments(parser, tcp_port, listen_host)


def split_ros_args(argv: list[str]) -> tuple[list[str], list[str]]:
    """(own arguments, ROS arguments): ROS's start at --ros-args, as with `ros2 run`."""
    if "--ros-args" in argv:
        i = argv.index("--ros-args")
        return argv[:i], argv[i:]
    return argv, []


def graph_param_set(backend: str, overlays: list[Path], ros_args: list[str] = (),
                    layers=LAYERS, record: Path | None = None,
                    options: Callable[[ParamSet], None] | None = None) -> ParamSet:
    """The packaged YAML overlaid by `overlays`, the parameters of `ros_args` and what
    `options(params)` sets, checked as the nodes will check them (layers, record: the nodes
    started). Raises CommandLineError naming the option (and the file, line and key)."""
    try:
        params = ParamSet()
        read_param_files(default_params_files(backend), option="--backend", into=params)
        read_param_files(overlays, into=params)
        # the command line's parameters win over every file, as `ros2 run` users expect (each
        # node is given them in its overrides: rclpy ranks overrides above --ros-args)
        add_ros_args(params, list(ros_args))
        if record is not None:
            params.set("run_recorder", "path", str(record), "--record")
        if options is not None:
            options(params)
        check_graph(params, backend, layers, record is not None, hardware_base(backend))
    except ParamFileError as err:
        raise refusal(err) from None
    return params


def graph_params_check(ros_args: list[str], layers_of=lambda args: args.layers,
                       options: Callable[[argparse.Namespace, ParamSet], None] | None = None):
    """The check (cli_args.parse_command_line) of --params, --ros-args and the parameters the
    options set: it leaves the checked ParamSet in `args.param_set`."""

    def check(args: argparse.Namespace) -> None:
        args.param_set = graph_param_set(
            args.backend, args.params, ros_args, layers_of(args), args.record,
            None if options is None else lambda params: options(args, params))

    return check


def load_graph_params(parser: argparse.ArgumentParser, backend: str,
                      overlays: list[Path]) -> tuple[list[Path], dict[str, dict[str, Any]]]:
    """The packaged YAML overlaid by `overlays`; a bad file ends in parser.error (exit 2)."""
    try:
        params = graph_param_set(backend, overlays)
    except CommandLineError as err:
        parser.error(_one_line(str(err)))
    return [*default_params_files(backend), *overlays], params.values()


def print_foxglove_url(nodes: list, prog: str) -> None:
    """Say where the Foxglove app connects, if the graph has the bridge."""
    for node in nodes:
        if isinstance(node, FoxgloveBridgeNode):
            print(f"{prog}: Foxglove live view: connect the app to {node.url}", flush=True)


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return " ".join(text.split())


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="katana-run", description=__doc__.split("\n\n")[0])
    add_graph_arguments(parser)
    parser.add_argument("--layers", type=_layers, default=list(LAYERS), metavar="L[,L]",
                        help=f"which parts of the graph to start (default: {','.join(LAYERS)})")
    parser.add_argument("--duration", type=positive_seconds, default=None, metavar="S",
                        help="stop after S wall seconds (default: run until Ctrl-C)")
    return parser


def main(argv: list[str] | None = None) -> int:
    own, ros_args = split_ros_args(sys.argv[1:] if argv is None else list(argv))
    args = parse_command_line(build_parser(), own, [graph_params_check(ros_args)])
    files = [*default_params_files(args.backend), *args.params]
    params = args.param_set.values()

    # katana-run handles SIGINT/SIGTERM itself (spin_nodes): the nodes stop before the context
    rclpy.init(args=["katana-run", *ros_args], signal_handler_options=SignalHandlerOptions.NO)
    try:
        nodes = build_nodes(args.backend, params, layers=args.layers, record=args.record,
                            foxglove=foxglove_address(args))
    except (ParameterError, ValueError) as exc:
        print(f"katana-run: {_one_line(exc)}", file=sys.stderr)
        rclpy.try_shutdown()
        return EXIT_INVALID_CONFIGURATION
    except SystemExit as exc:
        print(exc, file=sys.stderr)
        rclpy.try_shutdown()
        return EXIT_INVALID_CONFIGURATION
    names = ", ".join(n.get_name() for n in nodes)
    print(f"katana-run: backend {args.backend}: {names} (parameters: "
          f"{', '.join(str(f) for f in files)})", flush=True)
    print_foxglove_url(nodes, "katana-run")
    return spin_nodes(nodes, "katana-run", args.duration,
                      executor=MultiThreadedExecutor(num_threads=EXECUTOR_THREADS),
                      limit_s=KATANA_RUN_SHUTDOWN_LIMIT_S)


if __name__ == "__main__":
    sys.exit(main())
