"""Start the Katana node graph as separate processes (full ROS 2 install: `ros2 launch`).

    ros2 launch katana_bringup sim.launch.py [backend:=sim|hardware] [params_file:=FILE]
        [record:=FILE.mcap]

The whole graph of docs/DESIGN.md: the arm (sim or hardware), the pick-and-place executor,
perception, block memory, fovea and the curiosity node.

Same nodes and the same parameter files, in the same order, as the all-in-one runner
(`ros2 run katana_bringup katana-run`, katana_bringup.run.default_params_files): graph.yaml
(the scene and the pick-and-place geometry under `/**`), the backend's file (backend_sim.yaml:
use_sim_time for every node, then sim.yaml; or backend_hardware.yaml: wall time), then
`params_file` when given (an overlay, as katana-run's --params). backend:=hardware starts
katana_driver's arm driver and camera node (katana_camera), with
katana_driver/config/hardware.yaml first. The packaged files are generated from the nodes'
parameter specs (katana_bringup.config_files).
"""

import os

from ament_index_python.packages import get_package_share_directory
from katana_bringup.run import default_params_files
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def _nodes(context) -> list:
    backend = LaunchConfiguration("backend").perform(context)
    overlay = LaunchConfiguration("params_file").perform(context)
    files = [str(f) for f in default_params_files(backend)] + ([overlay] if overlay else [])
    hardware = LaunchConfiguration("hardware_params_file").perform(context)
    nodes = []
    if backend == "sim":
        nodes.append(Node(package="katana_sim", executable="sim_node", name="sim_node",
                          parameters=files, output="screen"))
    else:
        nodes += [
            Node(package="katana_driver", executable="katana_driver_node",
                 name="katana_driver_node", parameters=[hardware, *files], output="screen"),
            Node(package="katana_camera", executable="camera_node", name="camera_node",
                 parameters=[hardware, *files], output="screen"),
        ]
    for package, executable in (
        ("katana_manipulation", "pick_place_executor"),
        ("katana_perception", "perception_node"),
        ("katana_perception", "block_memory_node"),
        ("katana_perception", "fovea_node"),
        ("katana_curiosity", "curiosity_node"),
    ):
        nodes.append(Node(package=package, executable=executable, name=executable,
                          parameters=files, output="screen"))
    record = LaunchConfiguration("record").perform(context)
    if record:  # as katana-run --record FILE.mcap
        nodes.append(Node(package="katana_bringup", executable="run_recorder",
                          name="run_recorder", parameters=[*files, {"path": record}],
                          output="screen"))
    return nodes


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        DeclareLaunchArgument("backend", default_value="sim",
                              choices=["sim", "hardware"],
                              description="sim: PyBullet; hardware: a real Katana and camera"),
        DeclareLaunchArgument("params_file", default_value="",
                              description="parameter YAML overlaid on the packaged config"),
        DeclareLaunchArgument("record", default_value="",
                              description="FILE.mcap: record the run's topics (rosbag2 MCAP)"),
        DeclareLaunchArgument("hardware_params_file",
                              default_value=os.path.join(
                                  get_package_share_directory("katana_driver"), "config",
                                  "hardware.yaml"),
                              description="parameter YAML of the driver and camera nodes"),
        OpaqueFunction(function=_nodes),
    ])
