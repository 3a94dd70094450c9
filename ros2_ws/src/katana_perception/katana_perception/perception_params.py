"""Parameters the perception nodes share (besides katana_common.scene.SCENE_PARAMS), and the
wait for a named memory/blocks that blocks_wait_s bounds."""

from __future__ import annotations

from pathlib import Path

from katana_common.futures import NumberedArrivals
from katana_common.param_spec import Param

from .core.colors import color_table_strings, parse_color_table
from .core.segmentation import Segmenter

#: katana-calibrate's extrinsics; when set it replaces camera_position and camera_rpy
EXTRINSICS_FILE = Param(
    "extrinsics_file", "",
    "Extrinsics YAML written by katana-calibrate; when set it replaces camera_position and "
    "camera_rpy (read-only).")

COLOR_TABLE = Param(
    "color_table", color_table_strings(),
    "One entry per block colour, 'name:lo-hi[,lo-hi]' hue intervals on OpenCV's 0..179 "
    "scale; the name is the block id (read-only).", min_length=1)


#: how long a request naming a memory/blocks (blocks_sequence) waits for it
BLOCKS_WAIT = Param(
    "blocks_wait_s", 2.0, "Longest wait for the memory/blocks a request names "
    "(blocks_sequence) before it is refused, s.", 0.0, 60.0, live=True)


def missing_blocks(arrivals: NumberedArrivals, sequence: int, values) -> str | None:
    """Wait (at most the node's blocks_wait_s) until memory/blocks number `sequence` or a later
    one is in `arrivals`; None once it is, else why a request naming it is refused."""
    wait_s = float(values["blocks_wait_s"])
    if arrivals.wait_for(int(sequence), wait_s):
        return None
    return (f"memory/blocks number {sequence} not received within {wait_s:g} s "
            f"(blocks_wait_s); the last was number {arrivals.number}")


def segmenter_from(values) -> Segmenter:
    """The segmenter of a node's parameters: its color_table and the scene's block_size."""
    return Segmenter(parse_color_table(values["color_table"]),
                     block_size=tuple(values["block_size"]))


def check_files_and_colors(values) -> str | None:
    """Cross-check of the shared parameters: the extrinsics file exists, the colour table
    parses."""
    path = values.get("extrinsics_file", "")
    if path and not Path(path).is_file():
        return f"parameter 'extrinsics_file': no such file {path!r}"
    if "color_table" in values:
        try:
            parse_color_table(values["color_table"])
        except ValueError as err:
            return f"parameter 'color_table': {err}"
    return None
