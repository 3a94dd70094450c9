"""Show the Katana URDF in RViz (full ROS 2 install): robot_state_publisher, sliders for the
joints, the arm's base placed at the origin of the table's frame "world" (as the simulation
places it), and rviz2 with this package's rviz/katana.rviz (fixed frame world; needs a desktop
install for rviz2 and joint_state_publisher_gui).

    ros2 launch katana_description display.launch.py [model:=450_6m180|400_6m180|300_6m180]
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def _nodes(context):
    model = LaunchConfiguration("model").perform(context)
    share = get_package_share_directory("katana_description")
    path = os.path.join(share, "urdf", f"katana_{model}.urdf")
    with open(path, encoding="utf-8") as fh:
        description = fh.read()
    return [
        Node(package="robot_state_publisher", executable="robot_state_publisher",
             parameters=[{"robot_description": description}]),
        Node(package="tf2_ros", executable="static_transform_publisher",
             arguments=["--frame-id", "world", "--child-frame-id", "katana_base_link"]),
        Node(package="joint_state_publisher_gui", executable="joint_state_publisher_gui"),
        Node(package="rviz2", executable="rviz2",
             arguments=["-d", os.path.join(share, "rviz", "katana.rviz")]),
    ]


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        DeclareLaunchArgument("model", default_value="450_6m180",
                              description="Katana type (a file urdf/katana_<model>.urdf)"),
        OpaqueFunction(function=_nodes),
    ])
