"""Pinhole model of the simulated overhead camera, shared by the renderer and CameraInfo. ROS-free.

The pose is that of `camera_optical_frame` in `world` (REP 103: z forward, x right in the image,
y down), given as a position and roll-pitch-yaw (fixed axes, R = Rz(yaw) Ry(pitch) Rx(roll)).
The default looks straight down from (0.22, 0, 0.75) with image row 0 towards +x and columns
increasing towards -y: rpy = (pi, 0, -pi/2). The principal point is the image centre in the
convention where pixel centres have integer coordinates, cx = (width - 1) / 2, which is what an
OpenGL render with a symmetric frustum produces, so rendered pixels and `project` agree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = (
        math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw),
        math.sin(yaw),
    )
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1.0]])
    ry = np.array([[cp, 0, sp], [0, 1.0, 0], [-sp, 0, cp]])
    rx = np.array([[1.0, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return rz @ ry @ rx


@dataclass(frozen=True)
class CameraModel:
    width: int = 640
    height: int = 480
    focal_px: float = 750.0
    position: tuple[float, float, float] = (0.22, 0.0, 0.75)
    rpy: tuple[float, float, float] = (math.pi, 0.0, -math.pi / 2)
    near: float = 0.05
    far: float = 3.0
    frame_id: str = "camera_optical_frame"

    @property
    def cx(self) -> float:
        return (self.width - 1) / 2.0

    @property
    def cy(self) -> float:
        return (self.height - 1) / 2.0

    @property
    def K(self) -> np.ndarray:  # noqa: N802 - the standard name
        return np.array([[self.focal_px, 0, self.cx], [0, self.focal_px, self.cy], [0, 0, 1.0]])

    @property
    def P(self) -> np.ndarray:  # noqa: N802
        return np.hstack([self.K, np.zeros((3, 1))])

    @property
    def rotation(self) -> np.ndarray:
        """Optical frame axes in world coordinates (columns)."""
        return rpy_matrix(*self.rpy)

    @property
    def vertical_fov_deg(self) -> float:
        return math.degrees(2.0 * math.atan(self.height / 2.0 / self.focal_px))

    def view_matrix(self) -> list[float]:
        """Column-major OpenGL view matrix for pybullet.getCameraImage."""
        r = self.rotation
        eye = np.asarray(self.position, float)
        forward, down = r[:, 2], r[:, 1]
        import pybullet as p  # noqa: PLC0415 - its banner (katana_sim.core.__getattr__)

        return p.computeViewMatrix(eye.tolist(), (eye + forward).tolist(), (-down).tolist())

    def projection_matrix(self) -> list[float]:
        import pybullet as p  # noqa: PLC0415 - its banner (katana_sim.core.__getattr__)

        return p.computeProjectionMatrixFOV(
            self.vertical_fov_deg, self.width / self.height, self.near, self.far
        )

    def project(self, points_world: np.ndarray) -> np.ndarray:
        """Pixel (u, v) of world points (N x 3); NaN for points behind the camera."""
        pts = np.atleast_2d(np.asarray(points_world, float))
        cam = (pts - np.asarray(self.position)) @ self.rotation  # world -> optical frame
        z = cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.focal_px * cam[:, 0] / z + self.cx
            v = self.focal_px * cam[:, 1] / z + self.cy
        uv = np.stack([u, v], axis=1)
        uv[z <= 0] = np.nan
        return uv

    def pixel_to_plane(self, u: float, v: float, z_plane: float) -> np.ndarray:
        """World point where the ray through pixel (u, v) meets the plane z = z_plane."""
        ray = self.rotation @ np.array(
            [(u - self.cx) / self.focal_px, (v - self.cy) / self.focal_px, 1.0])
        eye = np.asarray(self.position, float)
        if abs(ray[2]) < 1e-12:
            raise ValueError("ray parallel to the plane")
        t = (z_plane - eye[2]) / ray[2]
        return eye + t * ray

    def in_view(self, points_world: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        uv = self.project(points_world)
        return (
            np.isfinite(uv).all(axis=1)
            & (uv[:, 0] >= margin_px)
            & (uv[:, 0] <= self.width - 1 - margin_px)
            & (uv[:, 1] >= margin_px)
            & (uv[:, 1] <= self.height - 1 - margin_px)
        )
