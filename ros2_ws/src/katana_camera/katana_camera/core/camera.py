"""Overhead camera core (ROS-free): camera_info YAML and frame sources.

The YAML is the standard one written by ROS's camera_calibration (image_width, image_height,
camera_name, camera_matrix, distortion_model, distortion_coefficients, rectification_matrix,
projection_matrix; matrices as {rows, cols, data}). camera_info_manager is not on PyPI, so
the few lines that read it are here. Every number of K, D, R and P must be finite.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np
import yaml


class CameraInfoError(ValueError):
    """A camera_info YAML that cannot be used; the text names the file and the field."""


@dataclass(frozen=True)
class Calibration:
    width: int
    height: int
    camera_name: str
    k: tuple[float, ...]  # 3x3 row-major
    distortion_model: str
    d: tuple[float, ...]
    r: tuple[float, ...]  # 3x3
    p: tuple[float, ...]  # 3x4


def _matrix(doc: dict, key: str, rows: int, cols: int | None, path: str) -> tuple[float, ...]:
    entry = doc.get(key)
    if not isinstance(entry, dict) or "data" not in entry:
        raise CameraInfoError(f"{path}: '{key}' must be a mapping with rows, cols and data")
    data = entry["data"]
    numeric = isinstance(data, list) and all(
        isinstance(x, int | float) and not isinstance(x, bool) for x in data
    )
    if not numeric:
        raise CameraInfoError(f"{path}: '{key}.data' must be a list of numbers")
    if cols is not None and len(data) != rows * cols:
        raise CameraInfoError(f"{path}: '{key}' needs {rows * cols} numbers, has {len(data)}")
    if not all(math.isfinite(float(x)) for x in data):
        raise CameraInfoError(f"{path}: '{key}' contains NaN or infinity")
    return tuple(float(x) for x in data)


def load_calibration(path: str | Path) -> Calibration:
    """Read a camera_info YAML; raises CameraInfoError saying what is wrong."""
    path = str(path)
    try:
        with open(path, encoding="utf-8") as stream:
            doc = yaml.safe_load(stream)
    except OSError as exc:
        raise CameraInfoError(f"{path}: cannot read ({exc.strerror})") from exc
    except yaml.YAMLError as exc:
        raise CameraInfoError(f"{path}: not valid YAML ({exc})") from exc
    if not isinstance(doc, dict):
        raise CameraInfoError(f"{path}: expected a mapping of camera_info fields")
    try:
        width, height = int(doc["image_width"]), int(doc["image_height"])
    except (KeyError, TypeError, ValueError) as exc:
        raise CameraInfoError(f"{path}: image_width and image_height must be integers") from exc
    if width <= 0 or height <= 0:
        raise CameraInfoError(f"{path}: image size {width}x{height} must be positive")
    k = _matrix(doc, "camera_matrix", 3, 3, path)
    if k[0] <= 0.0 or k[4] <= 0.0:
        raise CameraInfoError(f"{path}: camera_matrix focal lengths must be positive")
    d = _matrix(doc, "distortion_coefficients", 1, None, path)
    r = (
        _matrix(doc, "rectification_matrix", 3, 3, path)
        if "rectification_matrix" in doc
        else (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    )
    if "projection_matrix" in doc:
        p = _matrix(doc, "projection_matrix", 3, 4, path)
    else:
        p = (k[0], k[1], k[2], 0.0, k[3], k[4], k[5], 0.0, 0.0, 0.0, 1.0, 0.0)
    return Calibration(
        width=width,
        height=height,
        camera_name=str(doc.get("camera_name", "camera")),
        k=k,
        distortion_model=str(doc.get("distortion_model", "plumb_bob")),
        d=d,
        r=r,
        p=p,
    )


class FrameSource(Protocol):
    """Where frames come from: the real camera, a video file, or a substitute for tests."""

    description: str

    def open(self) -> bool: ...

    def read(self) -> np.ndarray | None:
        """One RGB frame (H x W x 3, uint8), or None when the source failed."""
        ...

    def release(self) -> None: ...


class OpenCvFrameSource:
    """A V4L2 camera (an index such as "0", or a path such as /dev/video0) or a video file."""

    def __init__(self, device: str, width: int = 640, height: int = 480, rate: float = 15.0):
        self.device = device
        self.width, self.height, self.rate = width, height, rate
        self.description = f"camera '{device}'"
        self._cap: cv2.VideoCapture | None = None

    def open(self) -> bool:
        self.release()
        target: int | str = int(self.device) if self.device.isdigit() else self.device
        cap = cv2.VideoCapture(target)
        if not cap.isOpened():
            cap.release()
            return False
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
        cap.set(cv2.CAP_PROP_FPS, self.rate)
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # fresh frames: V4L2 queues several by default
        self._cap = cap
        return True

    def read(self) -> np.ndarray | None:
        if self._cap is None:
            return None
        ok, frame = self._cap.read()
        if not ok or frame is None:
            return None
        if frame.ndim == 2:
            return cv2.cvtColor(frame, cv2.COLOR_GRAY2RGB)
        return cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)

    def release(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


class SubstituteFrameSource:
    """A SUBSTITUTE for the camera in tests and dry runs: synthetic frames, no real image.

    Light grey table with four coloured squares that drift one pixel per frame, so that a
    consumer can tell frames apart. ``fail_after`` frames, it stops (an unplugged camera).
    """

    description = "SUBSTITUTE frame source (synthetic test frames, not a camera)"

    def __init__(self, width: int = 640, height: int = 480, fail_after: int | None = None):
        self.width, self.height = width, height
        self.fail_after = fail_after
        self.frames = 0
        self.opened = False

    def open(self) -> bool:
        if self.fail_after is not None and self.frames >= self.fail_after:
            return False
        self.opened = True
        return True

    def read(self) -> np.ndarray | None:
        if not self.opened:
            return None
        if self.fail_after is not None and self.frames >= self.fail_after:
            self.opened = False
            return None
        image = np.full((self.height, self.width, 3), 200, dtype=np.uint8)
        colours = ((200, 30, 30), (30, 160, 60), (30, 60, 200), (220, 200, 40))
        shift = self.frames % 40
        for i, colour in enumerate(colours):
            u = 120 + 120 * i + shift
            v = self.height // 2 - 20
            image[v : v + 40, u : u + 40] = colour
        self.frames += 1
        return image

    def release(self) -> None:
        self.opened = False


def make_frame_source(device: str, width: int, height: int, rate: float) -> FrameSource:
    """``device`` "substitute" gives the synthetic test source; anything else goes to OpenCV."""
    if device == "substitute":
        return SubstituteFrameSource(width, height)
    return OpenCvFrameSource(device, width, height, rate)


class RateLimiter:
    """Sleep-free pacing helper: True when the next frame is due."""

    def __init__(self, rate: float) -> None:
        self.period = 1.0 / rate
        self.next = time.monotonic()

    def wait_time(self) -> float:
        return max(0.0, self.next - time.monotonic())

    def tick(self) -> None:
        self.next = max(self.next + self.period, time.monotonic())
