"""ROS-free PyBullet physics of the Katana (see physics.py for the API; pacing.py for how far
it runs and when)."""

from katana_sim.core.camera import CameraModel
from katana_sim.core.config import ConfigError, SimConfig
from katana_sim.core.controllers import TrajectoryGoal
from katana_sim.core.physics import BlockState, PhysicsSim

__all__ = [
    "BlockState",
    "CameraModel",
    "ConfigError",
    "SimConfig",
    "PhysicsSim",
    "TrajectoryGoal",
]
