"""Camera frames around each experiment of a run, for katana-demo's frames/ and katana-robot's
contact sheet: one recorder, on any node of the graph (or of a graph watching another process).

ExperienceFrames keeps the newest camera image and hands every curiosity/experience, with the
frames around it, to a callback: the scene before (the newest image when the experiment before
it was reported), the scene after (the newest image now) and, when it follows the
pick_and_place feedback, the scene when the motion started and the first images of its pick
(block in the gripper) and of its place (block released). draw_placement draws the fovea
window and the placement on a frame.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from katana_common.qos import EVENT_QOS, SENSOR_QOS
from katana_interfaces.action import PickAndPlace
from katana_interfaces.msg import Experience
from katana_perception.messages import image_to_rgb
from sensor_msgs.msg import Image

#: pick_and_place phases whose camera images show the pick (block in the gripper) and the
#: place (block released)
PHASE_COLUMN = {"lift": "pick", "carry": "pick", "lower": "pick", "release": "place",
                "retreat": "place", "park": "place"}


def draw_placement(rgb: np.ndarray, u: float, v: float, bits, text: str, fovea_px: int = 40,
                   offset_px: float = 10.0, stable: bool | None = None) -> np.ndarray:
    """The fovea window, its five test points (filled: inside the hull) and a caption (BGR)."""
    bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    colour = (0, 200, 255) if stable is None else ((0, 200, 0) if stable else (0, 0, 230))
    half = fovea_px / 2
    cv2.rectangle(bgr, (round(u - half), round(v - half)), (round(u + half), round(v + half)),
                  colour, 1)
    points = [(0, 0), (offset_px, offset_px), (-offset_px, offset_px), (-offset_px, -offset_px),
              (offset_px, -offset_px)]
    for (du, dv), on in zip(points, list(bits) + [False] * (5 - len(bits)), strict=False):
        cv2.circle(bgr, (round(u + du), round(v + dv)), 3, colour, -1 if on else 1)
    cv2.putText(bgr, text, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, colour, 2, cv2.LINE_AA)
    return bgr


@dataclass(frozen=True)
class Frames:
    """The RGB frames around one experiment (None: not seen)."""

    before: np.ndarray | None  # newest image when the experiment before was reported
    after: np.ndarray | None  # newest image when this one was reported
    motion_start: np.ndarray | None = None  # newest image at the motion's first feedback
    pick: np.ndarray | None = None  # first image of the pick phases
    place: np.ndarray | None = None  # first image of the place phases


class ExperienceFrames:
    """Subscribes `node` to the camera and curiosity/experience (and, with `phases`, to the
    pick_and_place feedback); calls on_experiment(msg, frames) for every experience."""

    def __init__(self, node, on_experiment: Callable[[Experience, Frames], None],
                 phases: bool = False) -> None:
        self.on_experiment = on_experiment
        self._lock = threading.Lock()
        self._latest: np.ndarray | None = None
        self._before: np.ndarray | None = None
        self._motion: dict[str, np.ndarray] = {}  # this motion's start, pick and place frames
        self._phase: str | None = None
        node.create_subscription(Image, "camera/image_raw", self._on_image, SENSOR_QOS)
        node.create_subscription(Experience, "curiosity/experience", self._on_experience,
                                 EVENT_QOS)
        if phases:
            node.create_subscription(PickAndPlace.Impl.FeedbackMessage,
                                     "pick_and_place/_action/feedback", self._on_feedback, 10)

    def _on_image(self, msg) -> None:
        try:
            rgb = image_to_rgb(msg)
        except ValueError:
            return
        with self._lock:
            self._latest = rgb
            if self._before is None:
                self._before = rgb
            column = PHASE_COLUMN.get(self._phase or "")
            if column and column not in self._motion:
                self._motion[column] = rgb

    def _on_feedback(self, msg) -> None:
        with self._lock:
            if "start" not in self._motion and self._latest is not None:
                self._motion["start"] = self._latest
            self._phase = msg.feedback.phase

    def _on_experience(self, msg) -> None:
        with self._lock:
            motion, self._motion, self._phase = self._motion, {}, None
            frames = Frames(self._before, self._latest, motion.get("start"),
                            motion.get("pick"), motion.get("place"))
            self._before = self._latest  # the scene after this experiment is the next's before
        self.on_experiment(msg, frames)
