"""ROS-free kinematics and pick-and-place sequence."""
