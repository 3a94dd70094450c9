"""ROS-free PyBullet physics of the Katana (see physics.py for the API; pacing.py for how far
it runs and when)."""

from katana_description.arm_contract import TrajectoryGoal

from katana_sim.core.camera import CameraModel
from katana_sim.core.config import ConfigError, SimConfig
from katana_sim.core.ground_truth import BlockState
from katana_sim.core.physics import PhysicsSim

__all__ = [
    "BlockState",
    "CameraModel",
    "ConfigError",
    "SimConfig",
    "PhysicsSim",
    "TrajectoryGoal",
]
