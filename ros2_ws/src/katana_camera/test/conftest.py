"""Keep in-process ROS tests of this package off the network (before any rclpy.init)."""

import os

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")
