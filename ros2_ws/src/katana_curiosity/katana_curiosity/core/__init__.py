"""ROS-free core: predictors, query condition, planner, explorer, worlds, metrics."""
