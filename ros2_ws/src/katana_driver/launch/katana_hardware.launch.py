"""The hardware backend alone: katana_driver_node and camera_node (needs a full ROS 2 install).

ros2 launch katana_driver katana_hardware.launch.py host:=192.168.1.1 device:=/dev/video0
    [autostart:=true|false]

katana_driver_node is a lifecycle (managed) node, started as a launch_ros LifecycleNode. With
autostart true (its parameter's default) the node brings itself to active (configure, then
activate: the set-up and calibration) and back after an error; the bring-up sequence lives in
the node alone, so launch emits no transitions. autostart:=false leaves it unconfigured for
`ros2 lifecycle set /katana_driver_node configure` (then activate) or a lifecycle manager.

Every parameter comes from `config` (config/hardware.yaml, generated from the nodes' specs);
an argument given here overrides its one parameter, an argument left out leaves the file's
value (the defaults are stated once, in the specs, not again here).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode, Node

#: launch argument -> (node, description); each sets the node's parameter of the same name
OVERRIDES = {
    "host": ("katana_driver_node", "Katana 400/450 controller address"),
    "transport": ("katana_driver_node", "tcp (400/450) or serial (300)"),
    "serial_device": ("katana_driver_node", "Katana 300 serial device"),
    "device": ("camera_node", "overhead camera device"),
    "camera_info_file": ("camera_node", "camera_calibration YAML"),
}


def _nodes(context) -> list:
    cfg = LaunchConfiguration("config").perform(context)
    ns = LaunchConfiguration("namespace").perform(context)
    nodes = []
    for node in ("katana_driver_node", "camera_node"):
        given = {name: LaunchConfiguration(name).perform(context)
                 for name, (owner, _) in OVERRIDES.items() if owner == node}
        given = {name: value for name, value in given.items() if value}
        if node == "katana_driver_node":
            autostart = LaunchConfiguration("autostart").perform(context)
            if autostart:  # a bool parameter: the launch argument's text is not one
                given["autostart"] = autostart.lower() == "true"
            nodes.append(LifecycleNode(package="katana_driver", executable=node, name=node,
                                       namespace=ns, output="screen",
                                       parameters=[cfg, *([given] if given else [])]))
        else:
            nodes.append(Node(package="katana_camera", executable=node, name=node,
                              namespace=ns, output="screen",
                              parameters=[cfg, *([given] if given else [])]))
    return nodes


def generate_launch_description() -> LaunchDescription:
    config = os.path.join(get_package_share_directory("katana_driver"), "config", "hardware.yaml")
    declared = [
        DeclareLaunchArgument("config", default_value=config,
                              description="parameter YAML of the driver and the camera"),
        DeclareLaunchArgument("namespace", default_value="", description="namespace of both nodes"),
        DeclareLaunchArgument("autostart", default_value="", choices=["", "true", "false"],
                              description="the driver brings itself to active (true) or waits "
                              "for lifecycle transitions (false); '': the config file's"),
    ] + [
        DeclareLaunchArgument(name, default_value="",
                              description=f"{text} ('': the config file's)")
        for name, (_, text) in OVERRIDES.items()
    ]
    return LaunchDescription([*declared, OpaqueFunction(function=_nodes)])
