"""Start the Katana node graph as separate processes (full ROS 2 install: `ros2 launch`).

    ros2 launch katana_bringup sim.launch.py [backend:=sim|hardware] [params_file:=FILE]
        [record:=FILE.mcap] [frames:=katana|robot_state_publisher] [rviz:=true]
        [foxglove:=true [foxglove_port:=8765] [foxglove_host:=127.0.0.1]]

The whole graph of docs/DESIGN.md: the arm (sim or hardware), the frame tree, the
pick-and-place executor, perception, block memory, fovea and the curiosity node.

The frame tree (/tf, /tf_static, robot_description): frames:=katana (the default) runs
katana_description's frame_publisher, as katana-run does; frames:=robot_state_publisher runs
robot_state_publisher on the same URDF (katana_<model>.urdf, the model of frame_publisher's
section of the parameter files) and frame_publisher with robot_frames false, for the frames
robot_state_publisher does not know: world -> arm base and the camera.

Same nodes and the same parameter files, in the same order, as the all-in-one runner
(`ros2 run katana_bringup katana-run`, katana_bringup.run.default_params_files): graph.yaml
(the scene and the pick-and-place geometry under `/**`), the backend's file (backend_sim.yaml:
use_sim_time for every node, then sim.yaml; or backend_hardware.yaml: wall time), then
`params_file` when given (an overlay, as katana-run's --params). backend:=hardware starts
katana_driver's arm driver and camera node (katana_camera), with
katana_driver/config/hardware.yaml first. The driver is a lifecycle (managed) node, started
as a LifecycleNode: it brings itself to active (its autostart parameter, true by default; the
bring-up sequence lives in the node alone, so launch emits no transitions) and the graph waits
for it (arm_ready is true only while the driver is active). The packaged files are generated
from the nodes' parameter specs (katana_bringup.config_files).

Watching: rviz:=true opens rviz2 with katana_description's rviz/katana.rviz; foxglove:=true
starts foxglove_bridge (as katana-run --foxglove) for the Foxglove app. Either adds
robot_state_publisher (the arm's URDF on robot_description and its links on /tf, from
joint_states) and the arm's base at the origin of "world" on /tf_static, as the sim places it.
"""

import os

from ament_index_python.packages import get_package_share_directory
from katana_bringup.live_view import DEFAULT_HOST, DEFAULT_PORT
from katana_bringup.run import default_params_files, load_params
from katana_description import models, urdf_path
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode, Node


def _frame_nodes(frames: str, files: list[str]) -> list:
    """frame_publisher alone, or robot_state_publisher with frame_publisher for the scene."""
    if frames == "katana":
        return [Node(package="katana_description", executable="frame_publisher",
                     name="frame_publisher", parameters=files, output="screen")]
    params = load_params(files)
    own = {**params.get("/**", {}), **params.get("frame_publisher", {})}
    description = urdf_path(f"katana_{own.get('model', models.DEFAULT_MODEL)}.urdf").read_text(
        encoding="utf-8")
    return [
        # the same URDF and clock as frame_publisher (the scene's names are not its parameters)
        Node(package="robot_state_publisher", executable="robot_state_publisher",
             name="robot_state_publisher",
             parameters=[{"robot_description": description,
                          "use_sim_time": bool(own.get("use_sim_time", False))}],
             output="screen"),
        Node(package="katana_description", executable="frame_publisher",
             name="frame_publisher", parameters=[*files, {"robot_frames": False}],
             output="screen"),
    ]


def _flag(context, name: str) -> bool:
    return LaunchConfiguration(name).perform(context).lower() == "true"


def _viewers(context, files: list, backend: str) -> list:
    """rviz2 and the Foxglove bridge (the frames come from _frame_nodes), on the graph's clock."""
    clock = {"use_sim_time": backend == "sim"}
    nodes = []
    if _flag(context, "rviz"):
        nodes.append(Node(package="rviz2", executable="rviz2", parameters=[clock],
                          arguments=["-d", os.path.join(
                              get_package_share_directory("katana_description"), "rviz",
                              "katana.rviz")]))
    if _flag(context, "foxglove"):  # as katana-run --foxglove PORT --foxglove-host HOST
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
    nodes = _frame_nodes(LaunchConfiguration("frames").perform(context), files)
    if backend == "sim":
        nodes.append(Node(package="katana_sim", executable="sim_node", name="sim_node",
                          parameters=files, output="screen"))
    else:
        nodes += [
            LifecycleNode(package="katana_driver", executable="katana_driver_node",
                          name="katana_driver_node", namespace="",
                          parameters=[hardware, *files], output="screen"),
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
        DeclareLaunchArgument("frames", default_value="katana",
                              choices=["katana", "robot_state_publisher"],
                              description="who publishes the arm's frames and robot_description: "
                              "katana_description's frame_publisher or robot_state_publisher"),
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
        DeclareLaunchArgument("hardware_params_file",
                              default_value=os.path.join(
                                  get_package_share_directory("katana_driver"), "config",
                                  "hardware.yaml"),
                              description="parameter YAML of the driver and camera nodes"),
        OpaqueFunction(function=_nodes),
    ])
