"""Hardware backend for the all-in-one runner: the driver and (katana_camera's) camera nodes.

``build_hardware_nodes(params, context)`` returns the nodes that replace sim_node when
``backend:=hardware``. Spin them on a MultiThreadedExecutor with at least three threads for
the driver (its action callbacks wait for the arm while joint_states keeps flowing).
"""

from __future__ import annotations

import copy
import os
from typing import Any

import yaml
from ament_index_python.packages import get_package_share_directory
from katana_camera.camera_node import CameraNode
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter

from katana_driver.katana_driver_node import KatanaDriverNode

DRIVER = "katana_driver_node"
CAMERA = "camera_node"


def default_config_path() -> str:
    """config/hardware.yaml: installed share folder, else the source tree."""
    try:
        path = os.path.join(get_package_share_directory("katana_driver"), "config", "hardware.yaml")
        if os.path.exists(path):
            return path
    except Exception:  # noqa: BLE001 - not installed: use the source tree
        pass
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    return os.path.join(here, "config", "hardware.yaml")


def _section(doc: dict[str, Any], name: str) -> dict[str, Any]:
    entry = doc.get(name) or doc.get("/" + name) or {}
    if "ros__parameters" in entry:
        entry = entry["ros__parameters"] or {}
    if not isinstance(entry, dict):
        raise ValueError(f"parameters of {name} must be a mapping")
    return dict(entry)


def load_hardware_params(
    params: dict[str, Any] | None = None, path: str | None = None
) -> dict[str, dict[str, Any]]:
    """hardware.yaml's values overlaid with ``params`` ({node: {name: value}} or YAML-shaped)."""
    with open(path or default_config_path(), encoding="utf-8") as stream:
        doc = yaml.safe_load(stream) or {}
    merged = {DRIVER: _section(doc, DRIVER), CAMERA: _section(doc, CAMERA)}
    for name in (DRIVER, CAMERA):
        merged[name].update(_section(copy.deepcopy(params or {}), name))
    return merged


def build_hardware_nodes(
    params: dict[str, Any] | None, context: Context | None, namespace: str = ""
) -> list[Node]:
    """katana_driver_node and camera_node with hardware.yaml's parameters overlaid by
    ``params`` (keys ``katana_driver_node`` and ``camera_node``, flat or ``ros__parameters``).
    A bad value raises an exception naming the parameter."""
    merged = load_hardware_params(params)
    nodes: list[Node] = []
    try:
        for cls, name in ((KatanaDriverNode, DRIVER), (CameraNode, CAMERA)):
            overrides = [Parameter(k, value=v) for k, v in merged[name].items()]
            nodes.append(
                cls(
                    node_name=name,
                    namespace=namespace,
                    context=context,
                    parameter_overrides=overrides,
                )
            )
    except Exception:
        for node in nodes:
            node.destroy_node()
        raise
    return nodes
