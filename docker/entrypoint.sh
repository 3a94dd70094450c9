#!/usr/bin/env bash
# Source ROS 2 Jazzy and the built workspace, then run the command (the sim demo by default).
set -e
source "/opt/ros/${ROS_DISTRO:-jazzy}/setup.bash"
source /katana/install/setup.bash
exec "$@"
