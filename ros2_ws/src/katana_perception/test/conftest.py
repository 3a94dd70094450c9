"""Test set-up for katana_perception: keep DDS discovery on this host only."""

import os

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")
