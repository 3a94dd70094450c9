"""katana-run: the whole node graph in one process (for machines without ros2 launch).

    katana-run [--backend sim|hardware] [--params FILE ...] [--duration S]

Loads standard ROS parameter YAML files (`node_name: {ros__parameters: {...}}`, with `/**` for
every node) and hands each node its parameters as overrides, then spins every node on one
MultiThreadedExecutor. launch/sim.launch.py starts the same nodes, with the same YAML, as
separate processes for users with a full ROS 2 install.

The graph has three layers: "arm" (the backend's arm and camera nodes, and the pick-and-place
executor), "perception" (perception, block memory and fovea nodes) and "curiosity" (the
learner). `--layers` starts a subset, e.g. only the arm for a manipulation check.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

PACKAGE = "katana_bringup"
BACKENDS = ("sim", "hardware")
LAYERS = ("arm", "perception", "curiosity")
#: threads of the shared executor: action callbacks that wait on other actions each hold one
EXECUTOR_THREADS = 8


def config_dir() -> Path:
    """The installed config folder (ament index) or the source tree's."""
    try:
        from ament_index_python.packages import get_package_share_directory

        path = Path(get_package_share_directory(PACKAGE)) / "config"
        if path.is_dir():
            return path
    except Exception:  # not installed: fall back to the source tree
        pass
    return Path(__file__).resolve().parent.parent / "config"


def default_params_files(backend: str = "sim") -> list[Path]:
    """graph.yaml (the nodes above the arm) plus the backend's own: sim.yaml for the sim; the
    hardware nodes read katana_driver's hardware.yaml themselves."""
    files = [config_dir() / "graph.yaml"]
    if backend == "sim":
        files.append(config_dir() / "sim.yaml")
    return files


def load_params(paths: list[str | Path]) -> dict[str, dict[str, Any]]:
    """Merge ROS parameter YAML files into {node_name: {param: value}}; later files win.
    The wildcard entry `/**` (or `**`) applies to every node and is kept under '/**'."""
    merged: dict[str, dict[str, Any]] = {}
    for path in paths:
        with open(path, encoding="utf-8") as fh:
            data = yaml.safe_load(fh) or {}
        if not isinstance(data, dict):
            raise ValueError(f"{path}: expected a mapping of node names")
        for node, body in data.items():
            if not isinstance(body, dict) or "ros__parameters" not in body:
                raise ValueError(f"{path}: '{node}' has no ros__parameters mapping")
            name = "/**" if node in ("/**", "**") else str(node).lstrip("/")
            params = body["ros__parameters"] or {}
            merged.setdefault(name, {}).update(_flatten(params))
    return merged


def _flatten(params: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested mappings become dotted names, as ROS 2 does with parameter YAML."""
    out: dict[str, Any] = {}
    for key, value in params.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_flatten(value, name + "."))
        else:
            out[name] = value
    return out


def overrides_for(node_name: str, params: dict[str, dict[str, Any]]) -> list:
    """rclpy Parameters for one node: the wildcard entries, then the node's own."""
    from rclpy.parameter import Parameter

    values = {**params.get("/**", {}), **params.get(node_name, {})}
    return [Parameter(name, value=value) for name, value in values.items()]


def _sim_nodes(params: dict, context) -> list:
    from katana_sim.sim_node import SimNode

    return [SimNode(context=context, parameter_overrides=overrides_for("sim_node", params))]


def _hardware_nodes(params: dict, context) -> list:
    try:
        from katana_driver.bringup import build_hardware_nodes
    except ImportError as exc:
        raise SystemExit(
            "katana-run: backend 'hardware' needs katana_driver (katana_driver.bringup."
            f"build_hardware_nodes), which is not available: {exc}"
        ) from None
    return list(build_hardware_nodes(params, context))


#: backend name -> builder of the nodes that stand for the arm and the camera
BACKEND_BUILDERS: dict[str, Callable[[dict, Any], list]] = {
    "sim": _sim_nodes,
    "hardware": _hardware_nodes,
}


def _perception_nodes(params: dict, context) -> list:
    from katana_perception.block_memory_node import BlockMemoryNode
    from katana_perception.fovea_node import FoveaNode
    from katana_perception.perception_node import PerceptionNode

    return [
        cls(context=context, parameter_overrides=overrides_for(name, params))
        for cls, name in ((PerceptionNode, "perception_node"),
                          (BlockMemoryNode, "block_memory_node"), (FoveaNode, "fovea_node"))
    ]


def _curiosity_nodes(params: dict, context) -> list:
    from katana_curiosity.curiosity_node import CuriosityNode

    return [CuriosityNode(context=context,
                          parameter_overrides=overrides_for("curiosity_node", params))]


def build_nodes(
    backend: str,
    params: dict[str, dict[str, Any]],
    context=None,
    layers: tuple[str, ...] | list[str] = LAYERS,
) -> list:
    """Every node of the chosen layers of the graph for a backend, constructed in `context`.

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
            from katana_manipulation.pick_place_executor import PickPlaceExecutor

            nodes += BACKEND_BUILDERS[backend](params, context)
            nodes.append(PickPlaceExecutor(
                context=context,
                parameter_overrides=overrides_for("pick_place_executor", params)))
        if "perception" in layers:
            nodes += _perception_nodes(params, context)
        if "curiosity" in layers:
            nodes += _curiosity_nodes(params, context)
    except BaseException:
        for node in nodes:
            node.destroy_node()
        raise
    return nodes


def _layers(text: str) -> list[str]:
    layers = [x.strip() for x in text.split(",") if x.strip()]
    bad = [x for x in layers if x not in LAYERS]
    if not layers or bad:
        raise argparse.ArgumentTypeError(f"choose from {','.join(LAYERS)}, got {text!r}")
    return layers


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="katana-run", description=__doc__.split("\n\n")[0])
    parser.add_argument("--backend", choices=BACKENDS, default="sim")
    parser.add_argument("--params", action="append", default=None, metavar="FILE",
                        help="ROS parameter YAML (repeatable; default: config/graph.yaml, "
                        "plus config/sim.yaml for the sim)")
    parser.add_argument("--layers", type=_layers, default=list(LAYERS), metavar="L[,L]",
                        help=f"which parts of the graph to start (default: {','.join(LAYERS)})")
    parser.add_argument("--duration", type=float, default=None, metavar="S",
                        help="stop after S wall seconds (default: run until Ctrl-C)")
    args, ros_args = parser.parse_known_args(sys.argv[1:] if argv is None else argv)
    if args.duration is not None and args.duration <= 0:
        parser.error("--duration must be positive")
    files = args.params or default_params_files(args.backend)
    try:
        params = load_params(files)
    except (OSError, ValueError, yaml.YAMLError) as exc:
        print(f"katana-run: cannot read parameters: {exc}", file=sys.stderr)
        return 2

    import rclpy
    from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
    from rclpy.task import Future

    rclpy.init(args=ros_args)
    try:
        nodes = build_nodes(args.backend, params, layers=args.layers)
    except Exception as exc:
        print(f"katana-run: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    executor = MultiThreadedExecutor(num_threads=EXECUTOR_THREADS)
    for node in nodes:
        executor.add_node(node)
    names = ", ".join(n.get_name() for n in nodes)
    print(f"katana-run: backend {args.backend}: {names} (parameters: "
          f"{', '.join(str(f) for f in files)})", flush=True)
    try:
        if args.duration is None:
            executor.spin()
        else:  # a future nobody completes: spin for the duration
            executor.spin_until_future_complete(Future(), timeout_sec=args.duration)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        for node in nodes:
            executor.remove_node(node)
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
