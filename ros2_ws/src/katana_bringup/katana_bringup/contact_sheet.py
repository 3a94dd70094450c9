"""The contact sheet of a robot run (cf. the paper's Figures 10-12): consecutive experiments of
a run, one a row, in the paper's four columns - the scene before (the fovea and the placement
drawn on it), the first image after the grasp, the first after the release, and the scene the
experiment left, with its label. katana-demo records it (`--contact-sheet`) in its own process:
an observer in another process would first have to discover the run's graph, which can take
longer than the first experiments (seconds, by the middleware's announcement period)."""

from __future__ import annotations

import threading
from collections.abc import Mapping, Sequence
from functools import partial
from pathlib import Path

import cv2
import numpy as np
from rclpy.node import Node

from .frames import ExperienceFrames, Frames, draw_placement

CONTACT_ROWS = 12


class ContactSheetRecorder:
    """Watches the run through `node` (of the run's graph) and keeps the rows of experiments
    first .. first + rows - 1 for `contact_sheet`."""

    def __init__(self, node: Node, first: int, rows: int = CONTACT_ROWS) -> None:
        self.first, self.n = first, rows
        self.rows: list[dict] = []
        self._lock = threading.Lock()
        self._handled = threading.Condition(self._lock)
        self._last_index = -1  # the last experiment handled
        self._pending = None  # the last row, until the next motion shows the scene it left
        self.frames = ExperienceFrames(node, self._on_experiment, phases=True)

    def wait_for(self, index: int, timeout_s: float) -> bool:
        """Until experiment `index` has been handled (its row kept, if it has one): the run's
        last experience may still be on its way when the run ends."""
        with self._handled:
            return self._handled.wait_for(lambda: self._last_index >= index, timeout_s)

    def _on_experiment(self, msg, frames: Frames) -> None:
        try:
            self._keep(msg, frames)
        finally:
            with self._handled:
                self._last_index = max(self._last_index, msg.index)
                self._handled.notify_all()

    def _keep(self, msg, frames: Frames) -> None:
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

    def write(self, path: Path) -> bool:
        """The sheet of the rows kept so far into `path`; False (nothing written) if none."""
        with self._lock:
            rows = list(self.rows)
        if rows:
            contact_sheet(rows, path)
        return bool(rows)


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
