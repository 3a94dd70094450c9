"""ROS-free PyBullet world of the Katana (see world.py for the API)."""

from katana_sim.core.camera import CameraModel
from katana_sim.core.config import ConfigError, SimConfig
from katana_sim.core.controllers import TrajectoryGoal
from katana_sim.core.world import BlockState, SimWorld

__all__ = [
    "BlockState",
    "CameraModel",
    "ConfigError",
    "SimConfig",
    "SimWorld",
    "TrajectoryGoal",
]
