"""ROS-free PyBullet physics of the Katana (see physics.py for the API; pacing.py for how far
it runs and when)."""

from katana_description.arm_contract import TrajectoryGoal

from katana_sim.core.camera import CameraModel
from katana_sim.core.config import ConfigError, SimConfig


def __getattr__(name: str):
    """PhysicsSim on first use (PEP 562): importing pybullet prints its banner to stdout, which
    a command line that only validates its options, or prints its usage, must not show."""
    if name == "PhysicsSim":
        from katana_sim.core.physics import PhysicsSim  # noqa: PLC0415 - pybullet: its banner
        return PhysicsSim
    if name == "BlockState":
        from katana_sim.core.ground_truth import BlockState  # noqa: PLC0415 - as above
        return BlockState
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "BlockState",
    "CameraModel",
    "ConfigError",
    "SimConfig",
    "PhysicsSim",
    "TrajectoryGoal",
]
