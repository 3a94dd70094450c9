"""PyBullet simulation of the Katana: the ROS-free world (core/) and sim_node."""
