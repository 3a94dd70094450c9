"""Configuration of the simulated world, validated in one place. ROS-free."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from katana_description import models as m

from katana_sim.core.camera import CameraModel

MAX_BLOCKS = 8


class ConfigError(ValueError):
    """An invalid configuration value; `param` names the parameter."""

    def __init__(self, param: str, message: str) -> None:
        super().__init__(f"parameter '{param}': {message}")
        self.param = param


@dataclass
class SimConfig:
    """Everything that shapes the world. Defaults are the shared scene defaults."""

    model: str = m.DEFAULT_MODEL
    num_blocks: int = 4
    block_colors: tuple[str, ...] = m.DEFAULT_COLOURS
    block_size: tuple[float, float, float] = m.BLOCK_SIZE
    block_mass: float = m.BLOCK_MASS
    seed: int = 0
    physics_rate: float = 240.0
    camera: CameraModel = field(default_factory=CameraModel)
    # Play area (the reach annulus of a top-down grasp, inside the camera's view).
    play_x: tuple[float, float] = (0.14, 0.30)
    play_y: tuple[float, float] = (-0.16, 0.16)
    # The robot loop resets the world when a block lies beyond the pick reach of a table block
    # (0.283 m: katana_manipulation.core.reach.pick_reach(1)); the scatter stays 8 mm inside it
    # so that a block perceived a few mm off is not out of reach right after a reset.
    play_radius: tuple[float, float] = (0.14, 0.275)
    min_gap: float = 0.015  # between the circumscribed circles of two scattered blocks
    block_friction: float = 0.9
    finger_friction: float = 1.5
    gripper_effort: float = 0.5  # N m, default finger motor torque
    arm_urdf: str = ""  # override of the arm's URDF file; empty: the model's own
    # The arm moves along its plan without physics steps while it is clear of every block and
    # of the table by FREE_SPACE_MARGIN_M and nothing else moves (physics.PhysicsSim.step).
    kinematic_free_space: bool = True

    def validate(self) -> SimConfig:
        """Raise ConfigError naming the first invalid parameter; return self otherwise."""
        try:
            m.get_model(self.model)
        except ValueError as exc:
            raise ConfigError("model", str(exc)) from None
        if not 1 <= self.num_blocks <= MAX_BLOCKS:
            raise ConfigError("num_blocks", f"{self.num_blocks} is outside 1..{MAX_BLOCKS}")
        colours = list(self.block_colors)
        if len(colours) < self.num_blocks:
            raise ConfigError(
                "block_colors", f"{len(colours)} colours for {self.num_blocks} blocks"
            )
        used = colours[: self.num_blocks]
        for c in used:
            if c not in m.COLOURS:
                raise ConfigError("block_colors", f"unknown colour '{c}'; known: {list(m.COLOURS)}")
        if len(set(used)) != len(used):
            raise ConfigError(
                "block_colors", f"colours must differ (blocks are told apart by colour): {used}"
            )
        if len(self.block_size) != 3 or not all(
            math.isfinite(v) and 0.01 <= v <= 0.08 for v in self.block_size
        ):
            raise ConfigError("block_size", f"{list(self.block_size)}: three edges in 0.01..0.08 m")
        if not (math.isfinite(self.block_mass) and 0.001 <= self.block_mass <= 0.4):
            raise ConfigError("block_mass", f"{self.block_mass} is outside 0.001..0.4 kg")
        if not (math.isfinite(self.physics_rate) and 60.0 <= self.physics_rate <= 5000.0):
            raise ConfigError("physics_rate", f"{self.physics_rate} is outside 60..5000 Hz")
        cam = self.camera
        if not (16 <= cam.width <= 4096 and 16 <= cam.height <= 4096):
            raise ConfigError("image_width", f"{cam.width}x{cam.height}: each side in 16..4096")
        if not (math.isfinite(cam.focal_px) and cam.focal_px > 1.0):
            raise ConfigError("camera_focal_px", f"{cam.focal_px} must be > 1")
        if len(cam.position) != 3 or not all(math.isfinite(v) for v in cam.position):
            raise ConfigError("camera_position", "three finite numbers (m)")
        if len(cam.rpy) != 3 or not all(math.isfinite(v) for v in cam.rpy):
            raise ConfigError("camera_rpy", "three finite numbers (rad)")
        for name in ("play_x", "play_y", "play_radius"):
            lo, hi = getattr(self, name)
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ConfigError(name, f"({lo}, {hi}) is not an interval")
        if not 0.0 <= self.min_gap <= 0.1:
            raise ConfigError("min_gap", f"{self.min_gap} is outside 0..0.1 m")
        for name in ("block_friction", "finger_friction", "gripper_effort"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0.0 < v <= 10.0):
                raise ConfigError(name, f"{v} is outside (0, 10]")
        return self

    @property
    def colours(self) -> list[str]:
        return list(self.block_colors[: self.num_blocks])
