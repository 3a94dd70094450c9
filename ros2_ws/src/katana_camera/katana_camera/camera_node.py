"""camera_node: the real overhead camera through OpenCV, as camera/image_raw and camera_info.

Frames are grabbed in a thread (a blocking read never holds the executor) and published as
rgb8 with sensor-data QoS, with the calibration from a standard camera_info YAML. A missing
or unplugged camera is logged as a clear error and reopened every ``reconnect_period``; the
node keeps running. ``device: substitute`` selects a SUBSTITUTE synthetic source for tests
and dry runs. Stamps are wall time at the grab (hardware runs on wall time).

Parameters: rate, frame_id and reconnect_period are live; device, width, height and
camera_info_file are read-only (they are what the camera was opened with).
"""

from __future__ import annotations

import os
import sys
import threading
import time

import numpy as np
from ament_index_python.packages import get_package_share_directory
from katana_common.messages import time_msg
from katana_common.node_runner import run_node
from katana_common.params import Param, ParameterError, declare_parameters
from katana_common.qos import SENSOR_QOS
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image

from katana_camera.core.camera import (
    Calibration,
    CameraInfoError,
    FrameSource,
    RateLimiter,
    load_calibration,
    make_frame_source,
)

PARAMS = (
    Param("device", "/dev/video0",
          "V4L2 device path or index, a video file, or 'substitute' (synthetic test frames)",
          nonempty=True),
    Param("width", 640, "requested image width, px", low=16, high=4096),
    Param("height", 480, "requested image height, px", low=16, high=4096),
    Param("rate", 15.0, "publishing rate, Hz", low=0.5, high=60.0, live=True),
    Param("camera_info_file", "",
          "camera_info YAML from camera_calibration ('' = the package's NOMINAL intrinsics)"),
    Param("frame_id", "camera_optical_frame", "optical frame of the images (REP 103)",
          nonempty=True, live=True),
    Param("reconnect_period", 2.0, "s between attempts to reopen the camera", low=0.1,
          high=60.0, live=True),
)


def nominal_camera_info_path() -> str:
    """The package's nominal intrinsics (installed share folder, else the source tree)."""
    try:
        share = get_package_share_directory("katana_camera")
        path = os.path.join(share, "config", "camera_info_nominal.yaml")
        if os.path.exists(path):
            return path
    except Exception:  # noqa: BLE001 - not installed: fall back to the source tree
        pass
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    return os.path.join(here, "config", "camera_info_nominal.yaml")


def calibration_to_msg(cal: Calibration, frame_id: str) -> CameraInfo:
    msg = CameraInfo()
    msg.header.frame_id = frame_id
    msg.width, msg.height = cal.width, cal.height
    msg.distortion_model = cal.distortion_model
    msg.d = list(cal.d)
    msg.k = list(cal.k)
    msg.r = list(cal.r)
    msg.p = list(cal.p)
    return msg


class CameraNode(Node):
    """Publishes frames from a FrameSource; ``frame_source`` overrides the device (tests)."""

    def __init__(self, frame_source: FrameSource | None = None, **kwargs) -> None:
        kwargs.setdefault("node_name", "camera_node")
        super().__init__(**kwargs)
        self.params = params = declare_parameters(self, PARAMS)
        self.rate, self.frame_id = params["rate"], params["frame_id"]
        self.reconnect_period = params["reconnect_period"]
        info_file, device = params["camera_info_file"], params["device"]
        width, height = params["width"], params["height"]
        if not info_file:
            info_file = nominal_camera_info_path()
            self.get_logger().warning(
                f"camera_info_file not set: publishing NOMINAL intrinsics from {info_file}; "
                "calibrate the camera for real use (docs/hardware.md)"
            )
        try:
            self.calibration = load_calibration(info_file)
        except CameraInfoError as exc:  # a start-up configuration error, like a bad parameter
            raise ParameterError(f"parameter 'camera_info_file': {exc}") from exc
        self._info = calibration_to_msg(self.calibration, self.frame_id)
        self._limiter = RateLimiter(self.rate)
        params.on_change(self._apply)
        self.source = frame_source or make_frame_source(device, width, height, self.rate)
        self.frames_published = 0
        self.error = ""
        self._size_warned = False
        self._image_pub = self.create_publisher(Image, "camera/image_raw", SENSOR_QOS)
        self._info_pub = self.create_publisher(CameraInfo, "camera/camera_info", SENSOR_QOS)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="camera-grabber", daemon=True)
        self._thread.start()
        self.get_logger().info(f"capturing from {self.source.description} at {self.rate:g} Hz")

    def _apply(self, changed: dict) -> None:
        if "rate" in changed:
            self.rate = changed["rate"]
            self._limiter.period = 1.0 / self.rate
        if "frame_id" in changed:
            self.frame_id = changed["frame_id"]
            self._info.header.frame_id = self.frame_id
        if "reconnect_period" in changed:
            self.reconnect_period = changed["reconnect_period"]

    def _run(self) -> None:
        limiter = self._limiter
        opened = False
        while not self._stop.is_set():
            if not opened:
                opened = self.source.open()
                if not opened:
                    self._report(
                        f"cannot open {self.source.description}: check the 'device' parameter "
                        f"and that the camera is plugged in; retrying every "
                        f"{self.reconnect_period:g} s"
                    )
                    self._stop.wait(self.reconnect_period)
                    continue
                if self.error:
                    self.get_logger().info(f"{self.source.description} is back")
                self.error = ""
            self._stop.wait(limiter.wait_time())
            limiter.tick()
            frame = self.source.read()
            if frame is None:
                self.source.release()
                opened = False
                self._report(
                    f"{self.source.description} stopped delivering frames (disconnected?); "
                    "reopening"
                )
                continue
            self._publish(frame)
        self.source.release()

    def _report(self, message: str) -> None:
        if message != self.error:  # once per distinct problem, not once per retry
            self.get_logger().error(message)
        self.error = message

    def _publish(self, frame: np.ndarray) -> None:
        h, w = frame.shape[:2]
        if (w, h) != (self.calibration.width, self.calibration.height) and not self._size_warned:
            self._size_warned = True
            self.get_logger().warning(
                f"frames are {w}x{h} but the calibration is for "
                f"{self.calibration.width}x{self.calibration.height}"
            )
        stamp = time_msg(time.time())
        image = Image()
        image.header.stamp = stamp
        image.header.frame_id = self.frame_id
        image.height, image.width = h, w
        image.encoding = "rgb8"
        image.is_bigendian = 0
        image.step = w * 3
        image.data = np.ascontiguousarray(frame, dtype=np.uint8).tobytes()
        self._info.header.stamp = stamp
        try:
            self._image_pub.publish(image)
            self._info_pub.publish(self._info)
        except Exception:  # noqa: BLE001 - the context is shutting down
            return
        self.frames_published += 1

    def stop(self) -> None:
        """End the grabber thread at once (run_node calls it on shutdown)."""
        self._stop.set()
        self._thread.join(timeout=1.5)

    def destroy_node(self) -> None:
        self.stop()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return run_node(CameraNode, "camera_node", args)


if __name__ == "__main__":
    sys.exit(main())
