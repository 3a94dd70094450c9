"""The hardware backend alone: katana_driver_node and camera_node (needs a full ROS 2 install).

ros2 launch katana_driver katana_hardware.launch.py host:=192.168.1.1 device:=/dev/video0
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    config = os.path.join(get_package_share_directory("katana_driver"), "config", "hardware.yaml")
    args = {
        "config": (config, "parameter YAML of the driver and the camera"),
        "namespace": ("", "namespace of both nodes"),
        "host": ("192.168.1.1", "Katana 400/450 controller address"),
        "transport": ("tcp", "tcp (400/450) or serial (300)"),
        "serial_device": ("/dev/ttyUSB0", "Katana 300 serial device"),
        "device": ("/dev/video0", "overhead camera device"),
        "camera_info_file": ("", "camera_calibration YAML ('' = nominal intrinsics)"),
    }
    declared = [
        DeclareLaunchArgument(k, default_value=v, description=d) for k, (v, d) in args.items()
    ]
    cfg = LaunchConfiguration("config")
    ns = LaunchConfiguration("namespace")
    driver = Node(
        package="katana_driver",
        executable="katana_driver_node",
        name="katana_driver_node",
        namespace=ns,
        output="screen",
        parameters=[
            cfg,
            {
                "host": LaunchConfiguration("host"),
                "transport": LaunchConfiguration("transport"),
                "serial_device": LaunchConfiguration("serial_device"),
            },
        ],
    )
    camera = Node(
        package="katana_camera",
        executable="camera_node",
        name="camera_node",
        namespace=ns,
        output="screen",
        parameters=[
            cfg,
            {
                "device": LaunchConfiguration("device"),
                "camera_info_file": LaunchConfiguration("camera_info_file"),
            },
        ],
    )
    return LaunchDescription([*declared, driver, camera])
