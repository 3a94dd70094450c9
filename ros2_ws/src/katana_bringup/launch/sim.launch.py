"""Start the Katana node graph as separate processes (full ROS 2 install: `ros2 launch`).

    ros2 launch katana_bringup sim.launch.py [backend:=sim|hardware] [params_file:=FILE]
        [record:=FILE.mcap] [rviz:=true] [foxglove:=true [foxglove_port:=8765]
        [foxglove_host:=127.0.0.1]]

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

Watching: rviz:=true opens rviz2 with katana_description's rviz/katana.rviz; foxglove:=true
starts foxglove_bridge (as katana-run --foxglove) for the Foxglove app. Either adds
robot_state_publisher (the arm's URDF on robot_description and its links on /tf, from
joint_states) and the arm's base at the origin of "world" on /tf_static, as the sim places it.
"""

import os

from ament_index_python.packages import get_package_share_directory
from katana_bringup.live_view import DEFAULT_HOST, DEFAULT_PORT
from katana_bringup.run import default_params_files
from katana_description.models import DEFAULT_MODEL, MODELS
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def _flag(context, name: str) -> bool:
    return LaunchConfiguration(name).perform(context).lower() == "true"


def _viewers(context, files: list, backend: str) -> list:
    """rviz2, the Foxglove bridge, and what both need to show the arm (on the graph's clock)."""
    rviz, foxglove = _flag(context, "rviz"), _flag(context, "foxglove")
    clock = {"use_sim_time": backend == "sim"}
    nodes = []
    if rviz or foxglove:
        model = LaunchConfiguration("model").perform(context)
        share = get_package_share_directory("katana_description")
        with open(os.path.join(share, "urdf", f"katana_{model}.urdf"), encoding="utf-8") as fh:
            description = fh.read()
        nodes += [
            Node(package="robot_state_publisher", executable="robot_state_publisher",
                 parameters=[clock, {"robot_description": description}], output="screen"),
            Node(package="tf2_ros", executable="static_transform_publisher", parameters=[clock],
                 arguments=["--frame-id", "world", "--child-frame-id", "katana_base_link"]),
        ]
    if rviz:
        nodes.append(Node(package="rviz2", executable="rviz2", parameters=[clock],
                          arguments=["-d", os.path.join(
                              get_package_share_directory("katana_description"), "rviz",
                              "katana.rviz")]))
    if foxglove:  # as katana-run --foxglove PORT --foxglove-host HOST
        nodes.append(Node(package="katana_bringup", executable="foxglove_bridge",
                          name="foxglove_bridge", output="screen", parameters=[*files, {
                              "port": int(LaunchConfiguration("foxglove_port").perform(context)),
                              "host": LaunchConfiguration("foxglove_host").perform(context)}]))
    return nodes


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
    return nodes + _viewers(context, files, backend)


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        DeclareLaunchArgument("backend", default_value="sim",
                              choices=["sim", "hardware"],
                              description="sim: PyBullet; hardware: a real Katana and camera"),
        DeclareLaunchArgument("params_file", default_value="",
                              description="parameter YAML overlaid on the packaged config"),
        DeclareLaunchArgument("record", default_value="",
                              description="FILE.mcap: record the run's topics (rosbag2 MCAP)"),
        DeclareLaunchArgument("rviz", default_value="false", choices=["true", "false"],
                              description="open rviz2 with katana_description/rviz/katana.rviz"),
        DeclareLaunchArgument("foxglove", default_value="false", choices=["true", "false"],
                              description="serve the graph to the Foxglove app (foxglove_bridge)"),
        DeclareLaunchArgument("foxglove_port", default_value=str(DEFAULT_PORT),
                              description="TCP port of the Foxglove WebSocket server"),
        DeclareLaunchArgument("foxglove_host", default_value=DEFAULT_HOST,
                              description="address it listens on (0.0.0.0: every interface)"),
        DeclareLaunchArgument("model", default_value=DEFAULT_MODEL, choices=sorted(MODELS),
                              description="Katana type whose URDF the viewers show"),
        DeclareLaunchArgument("hardware_params_file",
                              default_value=os.path.join(
                                  get_package_share_directory("katana_driver"), "config",
                                  "hardware.yaml"),
                              description="parameter YAML of the driver and camera nodes"),
        OpaqueFunction(function=_nodes),
    ])
