"""ROS-free vision core: segmentation, calibration, block memory, fovea, judge."""
