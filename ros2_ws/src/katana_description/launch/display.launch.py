"""Show the Katana URDF in RViz (full ROS 2 install): the frame tree, sliders for the joints,
and rviz2 with this package's rviz/katana.rviz (fixed frame world; needs a desktop install for
rviz2 and joint_state_publisher_gui).

    ros2 launch katana_description display.launch.py [model:=450_6m180|400_6m180|300_6m180]
        [frames:=katana|robot_state_publisher]

frames:=katana (the default) runs this package's frame_publisher: robot_description, the arm's
/tf and /tf_static, world -> arm base and the overhead camera's frames. frames:=
robot_state_publisher runs robot_state_publisher on the same URDF, with frame_publisher
(robot_frames false) for the world and camera frames it does not know.
"""

import os

from ament_index_python.packages import get_package_share_directory
from katana_description import urdf_path
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def _nodes(context):
    model = LaunchConfiguration("model").perform(context)
    frames = LaunchConfiguration("frames").perform(context)
    nodes = [Node(package="katana_description", executable="frame_publisher",
                  name="frame_publisher",
                  parameters=[{"model": model, "robot_frames": frames == "katana"}])]
    if frames == "robot_state_publisher":
        description = urdf_path(f"katana_{model}.urdf").read_text(encoding="utf-8")
        nodes.append(Node(package="robot_state_publisher", executable="robot_state_publisher",
                          parameters=[{"robot_description": description}]))
    share = get_package_share_directory("katana_description")
    return [
        *nodes,
        Node(package="joint_state_publisher_gui", executable="joint_state_publisher_gui"),
        Node(package="rviz2", executable="rviz2",
             arguments=["-d", os.path.join(share, "rviz", "katana.rviz")]),
    ]


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        DeclareLaunchArgument("model", default_value="450_6m180",
                              description="Katana type (a file urdf/katana_<model>.urdf)"),
        DeclareLaunchArgument("frames", default_value="katana",
                              choices=["katana", "robot_state_publisher"],
                              description="who publishes the arm's frames and robot_description"),
        OpaqueFunction(function=_nodes),
    ])
