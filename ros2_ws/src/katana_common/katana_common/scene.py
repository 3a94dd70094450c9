"""The scene facts several nodes must agree on, declared one way (graph.yaml sets them once,
under `/**:`, for every node): the world frame, the block size and the overhead camera pose."""

from __future__ import annotations

import math

from katana_description import models

from .param_spec import Param

SCENE_PARAMS: tuple[Param, ...] = (
    Param("world_frame", "world", "Frame of every published pose (REP 105 'world': the table).",
          nonempty=True),
    Param("block_size", [float(v) for v in models.BLOCK_SIZE], "Block edge lengths x, y, z, m.",
          low=0.01, high=0.08, length=3),
    Param("camera_position", [float(v) for v in models.CAMERA_POSITION],
          "Optical centre of the overhead camera in the world frame, m.",
          low=-10.0, high=10.0, length=3),
    Param("camera_rpy", [float(v) for v in models.CAMERA_RPY],
          "Roll, pitch, yaw (fixed axes) of camera_optical_frame in the world frame, rad.",
          low=-2 * math.pi, high=2 * math.pi, length=3),
)
