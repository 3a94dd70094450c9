import os

# Node tests talk only within their own process (and their own rclpy Context).
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")
