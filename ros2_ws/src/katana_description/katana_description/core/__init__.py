"""ROS-free logic of katana_description's node (the frame tree of frame_publisher)."""
