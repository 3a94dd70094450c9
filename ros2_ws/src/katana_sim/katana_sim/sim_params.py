"""sim_node's parameters (katana_common Params) and the SimConfig they make.

Live (`ros2 param set` applies them at once): the output rates camera_rate, joint_state_rate,
ground_truth_rate and clock_rate. Every other parameter shapes the world or its pacing when the
node starts and is read-only.
"""

from __future__ import annotations

from collections.abc import Mapping

from katana_common.param_spec import Param
from katana_common.scene import SCENE_PARAMS
from katana_description import models as m

from katana_sim.core import CameraModel, SimConfig
from katana_sim.core.config import MAX_BLOCKS

RATE_PARAMS = {"camera": "camera_rate", "joints": "joint_state_rate",
               "truth": "ground_truth_rate", "clock": "clock_rate"}

PARAMS: tuple[Param, ...] = SCENE_PARAMS + (
    Param("model", m.DEFAULT_MODEL, "Katana type.", choices=tuple(sorted(m.MODELS))),
    Param("num_blocks", 4, "Number of blocks.", 1, MAX_BLOCKS),
    Param("block_colors", list(m.DEFAULT_COLOURS), "Block colours, distinct; the first "
          "num_blocks are used.", choices=tuple(m.COLOURS), min_length=1),
    Param("block_mass", m.BLOCK_MASS, "Block mass, kg.", 0.001, 0.4),
    Param("seed", 0, "Seed of the first scatter and of the reset sequence.", 0, 2**31 - 1),
    Param("physics_rate", 240.0, "Physics steps per simulated second, Hz.", 60.0, 5000.0),
    Param("kinematic_free_space", SimConfig.kinematic_free_space, "Move the arm, and a block "
          "held still in its grip, along the plan without physics steps while both are 1 cm "
          "clear of every other block and of the table, the fingers still and every other block "
          "at rest; false: physics steps throughout."),
    Param("real_time_factor", 1.0, "Simulated seconds per wall second; 0: fast lock-step mode "
          "(physics runs only inside the motions it serves, deterministic).", 0.0, 100.0),
    Param("camera_focal_px", 750.0, "Focal length fx = fy, px.", 10.0, 10000.0),
    Param("image_width", 640, "Image width, px.", 16, 4096),
    Param("image_height", 480, "Image height, px.", 16, 4096),
    Param("camera_rate", 10.0, "Images per simulated second; 0: none. In fast mode images are "
          "rendered while the arm is idle (the world at rest), none during motions.", 0.0, 60.0,
          live=True),
    Param("joint_state_rate", 25.0, "joint_states per simulated second.", 1.0, 1000.0,
          live=True),
    Param("ground_truth_rate", 2.0, "sim/ground_truth per simulated second.", 0.1, 100.0,
          live=True),
    Param("publish_clock", True, "Publish /clock (every node runs with use_sim_time)."),
    Param("clock_rate", 100.0, "/clock messages per simulated second.", 1.0, 1000.0, live=True),
    Param("camera_frame", "camera_optical_frame", "frame_id of the images.", nonempty=True),
    Param("play_x", [0.14, 0.30], "Scatter area: x min, max, m.", -1.0, 1.0, length=2),
    Param("play_y", [-0.16, 0.16], "Scatter area: y min, max, m.", -1.0, 1.0, length=2),
    Param("play_radius", list(SimConfig.play_radius), "Scatter area: distance from the pan "
          "axis min, max, m (a top-down pick of a table block reaches 0.283).", 0.0, 1.0,
          length=2),
)


def cross_check(values: Mapping) -> str | None:
    """Rules across parameters (start-up and live changes)."""
    colours = list(values["block_colors"])
    if len(colours) < values["num_blocks"]:
        return (f"parameter 'block_colors': {len(colours)} colours for num_blocks "
                f"{values['num_blocks']}")
    used = colours[: values["num_blocks"]]
    if len(set(used)) != len(used):
        return f"parameter 'block_colors': colours must differ (blocks are told apart): {used}"
    for name in ("play_x", "play_y", "play_radius"):
        lo, hi = values[name]
        if not lo < hi:
            return f"parameter '{name}': ({lo}, {hi}) is not an interval (min < max)"
    return None


def sim_config(values: Mapping) -> SimConfig:
    """The SimConfig of validated parameter values (SimConfig.validate raises ConfigError)."""
    cfg = SimConfig(
        model=values["model"],
        num_blocks=values["num_blocks"],
        block_colors=tuple(values["block_colors"]),
        block_size=tuple(values["block_size"]),
        block_mass=values["block_mass"],
        seed=values["seed"],
        physics_rate=values["physics_rate"],
        kinematic_free_space=values["kinematic_free_space"],
        camera=CameraModel(
            width=values["image_width"], height=values["image_height"],
            focal_px=values["camera_focal_px"], position=tuple(values["camera_position"]),
            rpy=tuple(values["camera_rpy"]), frame_id=values["camera_frame"]),
        play_x=tuple(values["play_x"]),
        play_y=tuple(values["play_y"]),
        play_radius=tuple(values["play_radius"]),
    )
    return cfg.validate()
