"""Start the Katana node graph as separate processes (full ROS 2 install: `ros2 launch`).

    ros2 launch katana_bringup sim.launch.py [backend:=sim|hardware] [params_file:=FILE]

The whole graph of DESIGN.md: the arm (sim or hardware), the pick-and-place executor,
perception, block memory, fovea and the curiosity node.

Same nodes and the same parameter YAML (config/graph.yaml, config/sim.yaml) as the all-in-one
runner (`ros2 run katana_bringup katana-run`). backend:=hardware starts katana_driver's arm
driver and camera node (parameters from katana_driver/config/hardware.yaml) instead of the
simulation.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import EqualsSubstitution, LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    bringup = get_package_share_directory("katana_bringup")
    backend = LaunchConfiguration("backend")
    params = LaunchConfiguration("params_file")
    sim_params = LaunchConfiguration("sim_params_file")
    hardware_params = LaunchConfiguration("hardware_params_file")
    is_sim = IfCondition(EqualsSubstitution(backend, "sim"))
    is_hardware = IfCondition(EqualsSubstitution(backend, "hardware"))
    return LaunchDescription([
        DeclareLaunchArgument("backend", default_value="sim",
                              choices=["sim", "hardware"],
                              description="sim: PyBullet; hardware: a real Katana and camera"),
        DeclareLaunchArgument("params_file",
                              default_value=os.path.join(bringup, "config", "graph.yaml"),
                              description="parameter YAML of the nodes above the arm"),
        DeclareLaunchArgument("sim_params_file",
                              default_value=os.path.join(bringup, "config", "sim.yaml"),
                              description="parameter YAML of sim_node"),
        DeclareLaunchArgument("hardware_params_file",
                              default_value=os.path.join(
                                  get_package_share_directory("katana_driver"), "config",
                                  "hardware.yaml"),
                              description="parameter YAML of the driver and camera nodes"),
        Node(package="katana_sim", executable="sim_node", name="sim_node",
             parameters=[params, sim_params], output="screen", condition=is_sim),
        Node(package="katana_driver", executable="katana_driver_node",
             name="katana_driver_node", parameters=[hardware_params, params], output="screen",
             condition=is_hardware),
        Node(package="katana_driver", executable="camera_node", name="camera_node",
             parameters=[hardware_params, params], output="screen", condition=is_hardware),
        Node(package="katana_manipulation", executable="pick_place_executor",
             name="pick_place_executor", parameters=[params], output="screen"),
        Node(package="katana_perception", executable="perception_node",
             name="perception_node", parameters=[params], output="screen"),
        Node(package="katana_perception", executable="block_memory_node",
             name="block_memory_node", parameters=[params], output="screen"),
        Node(package="katana_perception", executable="fovea_node",
             name="fovea_node", parameters=[params], output="screen"),
        Node(package="katana_curiosity", executable="curiosity_node",
             name="curiosity_node", parameters=[params], output="screen"),
    ])

