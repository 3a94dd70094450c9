"""The contact sheet of a robot run (cf. the paper's Figures 10-12): consecutive experiments of
a run in another process, one a row, in the paper's four columns - the scene before (the fovea
and the placement drawn on it), the first image after the grasp, the first after the release,
and the scene the experiment left, with its label."""

from __future__ import annotations

import os
import threading
from collections.abc import Mapping, Sequence
from functools import partial
from pathlib import Path

import cv2
import numpy as np
from katana_bringup.frames import ExperienceFrames, Frames, draw_placement
from katana_bringup.in_process import InProcessGraph

CONTACT_ROWS = 12


class ContactSheetRecorder:
    """Watches the run in ROS domain `domain_id` (another process on this machine) and keeps
    the rows of experiments first .. first + rows - 1 for `contact_sheet`."""

    def __init__(self, domain_id: int, first: int, rows: int = CONTACT_ROWS) -> None:
        self.first, self.n = first, rows
        self.rows: list[dict] = []
        self._lock = threading.Lock()
        self._pending = None  # the last row, until the next motion shows the scene it left
        self.graph = _graph_in_domain(domain_id)
        self.frames = ExperienceFrames(self.graph.node("contact_recorder"), self._on_experiment,
                                       phases=True)

    def _on_experiment(self, msg, frames: Frames) -> None:
        with self._lock:
            if self._pending is not None and frames.motion_start is not None:
                row, draw = self._pending  # the scene before this motion is the scene the
                row["images"][3] = draw(frames.motion_start)  # last experiment left
            self._pending = None
            if not self.first <= msg.index < self.first + self.n or len(self.rows) >= self.n:
                return
        inst = msg.instance

        def drawn(img, **kw):
            if img is None:
                return None
            return cv2.cvtColor(draw_placement(img, inst.pixel_u, inst.pixel_v, inst.bits, "",
                                               **kw), cv2.COLOR_BGR2RGB)

        row = {
            "caption": f"#{msg.index} {msg.mode}\nh={inst.state} a={inst.action}\n"
                       f"{'stayed' if msg.label > 0 else 'fell'} ({msg.label:+d})",
            "label": int(msg.label),
            "images": [drawn(frames.motion_start), frames.pick, frames.place,
                       drawn(frames.after, stable=msg.label > 0)],
        }
        with self._lock:
            self.rows.append(row)
            self._pending = (row, partial(drawn, stable=msg.label > 0))

    def close(self) -> None:
        self.graph.close()


def _graph_in_domain(domain_id: int) -> InProcessGraph:
    """A graph in another ROS domain whose discovery reaches the other processes of this
    machine (read once, at init; this process's own setting is put back for anything started
    later)."""
    saved = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE")
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    try:
        return InProcessGraph(threads=2, domain_id=domain_id, close_timeout_s=2.0)
    finally:
        if saved is None:
            del os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"]
        else:
            os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = saved


#: the paper's four columns (Figures 10-12)
CONTACT_COLUMNS = ("fovea search", "pick", "place", "observation")


def contact_sheet(rows: Sequence[Mapping], path: Path, width_px: int = 240) -> None:
    """Rows of {"caption": str, "images": [rgb|None] * 4, "label": +1|-1}: one experiment per
    row, the paper's four columns, each image scaled to `width_px`; a missing frame is grey."""
    tiles = []
    header = np.full((28, width_px * 4 + 150, 3), 255, np.uint8)
    for k, name in enumerate(CONTACT_COLUMNS):
        cv2.putText(header, name, (150 + k * width_px + 8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55,
                    (0, 0, 0), 1, cv2.LINE_AA)
    tiles.append(header)
    for row in rows:
        cells = []
        height = None
        for img in row["images"]:
            if img is None:
                continue
            height = int(round(img.shape[0] * width_px / img.shape[1]))
            break
        height = height or int(width_px * 0.75)
        for img in row["images"]:
            if img is None:
                cells.append(np.full((height, width_px, 3), 160, np.uint8))
            else:
                cells.append(cv2.resize(np.ascontiguousarray(img), (width_px, height),
                                        interpolation=cv2.INTER_AREA))
        side = np.full((height, 150, 3), 255, np.uint8)
        colour = (0, 150, 0) if row.get("label", 0) > 0 else (200, 0, 0)
        for j, line in enumerate(str(row["caption"]).split("\n")):
            cv2.putText(side, line, (6, 22 + 20 * j), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                        colour if j == len(str(row["caption"]).split("\n")) - 1 else (0, 0, 0),
                        1, cv2.LINE_AA)
        tiles.append(np.hstack([side, *cells]))
    sheet = np.vstack(tiles)
    cv2.imwrite(str(path), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
