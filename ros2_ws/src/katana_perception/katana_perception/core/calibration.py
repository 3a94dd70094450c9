"""Pixels <-> table frame for an overhead pinhole camera.

The camera cannot see height, so a pixel maps to a world point only once the height of the
plane it lies on is known: the table (z = 0) or the top of a stack (z = level * block height).
Intrinsics come from CameraInfo (or a camera_info YAML), the camera pose from parameters or
from an extrinsics YAML written by `katana-calibrate` (cv2.solvePnP on known points).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import yaml
from scipy.spatial.transform import Rotation

# Shared scene defaults (katana_bringup/config): optical centre above the play area, looking
# straight down, image row 0 towards +x, columns increasing towards -y.
DEFAULT_CAMERA_POSITION = (0.22, 0.0, 0.75)
# camera_optical_frame in world: x_cam = -y_world, y_cam = -x_world, z_cam = -z_world, i.e.
# roll-pitch-yaw (fixed axes, R = Rz(yaw) Ry(pitch) Rx(roll)) = (pi, 0, -pi/2), as katana_sim.
DEFAULT_CAMERA_ORIENTATION = (0.7071067811865476, -0.7071067811865476, 0.0, 0.0)  # x, y, z, w
DEFAULT_WIDTH = 640
DEFAULT_HEIGHT = 480
DEFAULT_FX = 750.0
#: a camera's field of view along each image axis lies within these degrees
FIELD_OF_VIEW_DEG = (1.0, 170.0)
#: pixels of the image's middle half (each axis) mapped to the table and projected back land
#: this close to themselves. Distortion that cannot be inverted there misses by thousands of
#: pixels, or not at all; a strong real lens (93 degrees, k1 = -0.35) misses by 0.12 px
#: there, though its corners miss by up to 140 px (OpenCV's iterative undistortion).
ROUND_TRIP_PX = 2.0
ROUND_TRIP_GRID = 5  # pixels per image axis checked


def default_camera_matrix(
    width: int = DEFAULT_WIDTH, height: int = DEFAULT_HEIGHT, f: float = DEFAULT_FX
) -> np.ndarray:
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


@dataclass
class Calibration:
    """Intrinsics K, D plus the world->camera transform (OpenCV convention: X_c = R X_w + t)."""

    K: np.ndarray
    rvec: np.ndarray
    tvec: np.ndarray
    width: int = DEFAULT_WIDTH
    height: int = DEFAULT_HEIGHT
    D: np.ndarray = field(default_factory=lambda: np.zeros(5))
    R: np.ndarray = field(init=False, repr=False)
    centre: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.K = np.asarray(self.K, dtype=np.float64).reshape(3, 3)
        self.D = np.asarray(self.D, dtype=np.float64).ravel()
        self.rvec = np.asarray(self.rvec, dtype=np.float64).reshape(3)
        self.tvec = np.asarray(self.tvec, dtype=np.float64).reshape(3)
        if self.K[0, 0] <= 0 or self.K[1, 1] <= 0 or self.K[2, 2] != 1.0:
            raise ValueError(f"camera matrix is not a valid pinhole K: {self.K.tolist()}")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        self.R = cv2.Rodrigues(self.rvec)[0]
        self.centre = -self.R.T @ self.tvec

    # ---------------------------------------------------------------- construction
    @classmethod
    def from_camera_pose(cls, K: np.ndarray, position: Sequence[float],
                         orientation_xyzw: Sequence[float], width: int = DEFAULT_WIDTH,
                         height: int = DEFAULT_HEIGHT,
                         D: Sequence[float] | None = None) -> Calibration:
        """From the pose of camera_optical_frame in world (what a TF or a parameter gives)."""
        q = np.asarray(orientation_xyzw, dtype=np.float64)
        if q.shape != (4,) or not np.isfinite(q).all() or np.linalg.norm(q) < 1e-9:
            raise ValueError(f"camera orientation must be a quaternion x, y, z, w; got {q}")
        p = np.asarray(position, dtype=np.float64)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ValueError(f"camera position must be x, y, z; got {p}")
        r_wc = Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()  # camera axes in world
        r_cw = r_wc.T
        t = -r_cw @ p
        rvec = cv2.Rodrigues(r_cw)[0].ravel()
        return cls(K=K, rvec=rvec, tvec=t, width=width, height=height,
                   D=np.zeros(5) if D is None else np.asarray(D, dtype=np.float64))

    @classmethod
    def from_camera_rpy(cls, K: np.ndarray, position: Sequence[float], rpy: Sequence[float],
                        width: int = DEFAULT_WIDTH, height: int = DEFAULT_HEIGHT,
                        D: Sequence[float] | None = None) -> Calibration:
        """From position and roll-pitch-yaw (fixed axes) of camera_optical_frame in world."""
        r = np.asarray(rpy, dtype=np.float64)
        if r.shape != (3,) or not np.isfinite(r).all():
            raise ValueError(f"camera rpy must be three finite angles; got {r}")
        q = Rotation.from_euler("xyz", r).as_quat()
        return cls.from_camera_pose(K, position, q, width, height, D)

    @classmethod
    def overhead_default(cls) -> Calibration:
        """The shared scene default: 640x480, f = 750 px, 0.75 m above (0.22, 0)."""
        return cls.from_camera_pose(
            default_camera_matrix(), DEFAULT_CAMERA_POSITION, DEFAULT_CAMERA_ORIENTATION
        )

    def implausibility(self) -> str:
        """Why this cannot be a camera over the table, or "": its principal point outside the
        image, a field of view outside FIELD_OF_VIEW_DEG, no pixel of the image's middle
        seeing the table, or pixels there that do not map to the table and back to themselves
        within ROUND_TRIP_PX. A calibration that fails this projects blocks to pixels that are
        garbage (non-finite, or beyond what a mask can be drawn at), though each number in it
        is finite."""
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        if not (0.0 <= cx <= self.width and 0.0 <= cy <= self.height):
            return (f"the principal point ({cx:.6g}, {cy:.6g}) px is outside the "
                    f"{self.width}x{self.height} image")
        lo, hi = FIELD_OF_VIEW_DEG
        for axis, f, size in (("horizontal", fx, self.width), ("vertical", fy, self.height)):
            fov = math.degrees(2.0 * math.atan(size / (2.0 * f)))
            if not lo <= fov <= hi:
                return (f"the {axis} field of view is {fov:.3g} degrees ({size} px at a focal "
                        f"length of {f:.6g} px); a camera's is {lo:g} to {hi:g}")
        u, v = np.meshgrid(np.linspace(0.25, 0.75, ROUND_TRIP_GRID) * (self.width - 1.0),
                           np.linspace(0.25, 0.75, ROUND_TRIP_GRID) * (self.height - 1.0))
        u, v = u.ravel(), v.ravel()
        with np.errstate(all="ignore"):
            x, y = self.pixel_to_world(u, v, 0.0)
            seen = np.isfinite(x) & np.isfinite(y)
            if not seen.any():
                return ("no pixel of the image's middle sees the table (z = 0) from this "
                        "camera pose")
            pu, pv = self.world_to_pixel(x[seen], y[seen], 0.0)
            miss = np.hypot(pu - u[seen], pv - v[seen])
        worst = int(np.argmax(np.where(np.isfinite(miss), miss, np.inf)))
        if not np.isfinite(miss[worst]) or miss[worst] > ROUND_TRIP_PX:
            return (f"pixel ({u[seen][worst]:.0f}, {v[seen][worst]:.0f}) maps to the table and "
                    f"back to ({pu[worst]:.6g}, {pv[worst]:.6g}): the distortion "
                    f"{self.D.tolist()} cannot be inverted over the image")
        return ""

    # ---------------------------------------------------------------- pose
    @property
    def orientation_xyzw(self) -> np.ndarray:
        """Quaternion of camera_optical_frame in world."""
        return Rotation.from_matrix(self.R.T).as_quat()

    # ---------------------------------------------------------------- projection
    def pixel_to_world(self, u, v, z) -> tuple[np.ndarray, np.ndarray]:
        """Intersect the viewing ray of pixel (u, v) with the horizontal plane at height z."""
        u = np.asarray(u, dtype=np.float64)
        v = np.asarray(v, dtype=np.float64)
        shape = np.broadcast(u, v, np.asarray(z)).shape
        uv = np.stack(np.broadcast_arrays(u, v), axis=-1).reshape(-1, 1, 2)
        norm = cv2.undistortPoints(uv, self.K, self.D).reshape(-1, 2)
        rays_c = np.column_stack([norm, np.ones(len(norm))])
        rays_w = rays_c @ self.R  # R^T applied to each row
        zz = np.broadcast_to(np.asarray(z, dtype=np.float64), shape).ravel()
        dz = rays_w[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (zz - self.centre[2]) / dz
        s = np.where((np.abs(dz) < 1e-12) | (s <= 0), np.nan, s)  # ray misses the plane
        x = self.centre[0] + s * rays_w[:, 0]
        y = self.centre[1] + s * rays_w[:, 1]
        return x.reshape(shape), y.reshape(shape)

    def world_to_pixel(self, x, y, z) -> tuple[np.ndarray, np.ndarray]:
        """Project world points through the calibrated camera (with distortion)."""
        b = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float), np.asarray(z, float))
        pts = np.stack([a.ravel() for a in b], axis=-1).reshape(-1, 1, 3)
        uv, _ = cv2.projectPoints(pts, self.rvec, self.tvec, self.K, self.D)
        uv = uv.reshape(-1, 2)
        return uv[:, 0].reshape(b[0].shape), uv[:, 1].reshape(b[0].shape)

    def project(self, points: np.ndarray) -> np.ndarray:
        """Nx3 world points -> Nx2 pixels."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 1, 3)
        uv, _ = cv2.projectPoints(pts, self.rvec, self.tvec, self.K, self.D)
        return uv.reshape(-1, 2)

    def depth(self, points: np.ndarray) -> np.ndarray:
        """Distance along the optical axis of Nx3 world points (for painter's ordering)."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return (pts @ self.R.T + self.tvec)[:, 2]

    def nadir(self) -> np.ndarray:
        """Vanishing point of vertical lines: side faces of blocks lean away from it."""
        d = self.K @ (self.R @ np.array([0.0, 0.0, -1.0]))
        if abs(d[2]) < 1e-9:
            return np.array([np.inf, np.inf])
        return d[:2] / d[2]

    def pixels_per_metre(self, u: float, v: float, z: float) -> float:
        """Image scale of a horizontal plane at height z around pixel (u, v)."""
        x, y = self.pixel_to_world(u, v, z)
        pu, pv = self.world_to_pixel(
            [x + 0.005, x - 0.005, x, x], [y, y, y + 0.005, y - 0.005], [z] * 4
        )
        dx = np.hypot(pu[0] - pu[1], pv[0] - pv[1])
        dy = np.hypot(pu[2] - pu[3], pv[2] - pv[3])
        return float((dx + dy) / 2.0 / 0.01)

    def image_angle_to_yaw(self, u: float, v: float, angle: float, z: float) -> float:
        """World yaw of an image direction at pixel (u, v) on the plane at height z."""
        x, y = self.pixel_to_world(
            [u, u + 10.0 * np.cos(angle)], [v, v + 10.0 * np.sin(angle)], [z, z]
        )
        return float(np.arctan2(y[1] - y[0], x[1] - x[0]))

    def yaw_to_image_angle(self, x: float, y: float, yaw: float, z: float) -> float:
        """Image direction of the world direction `yaw` at world point (x, y, z)."""
        pu, pv = self.world_to_pixel(
            [x, x + 0.01 * np.cos(yaw)], [y, y + 0.01 * np.sin(yaw)], [z, z]
        )
        return float(np.arctan2(pv[1] - pv[0], pu[1] - pu[0]))

    def square_polygon(
        self, x: float, y: float, yaw: float, z: float, sx: float, sy: float
    ) -> np.ndarray:
        """Pixel polygon (4x2) of a horizontal sx-by-sy rectangle centred at (x, y, z)."""
        c, s = np.cos(yaw), np.sin(yaw)
        local = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], dtype=float) * [sx / 2, sy / 2]
        wx = x + local[:, 0] * c - local[:, 1] * s
        wy = y + local[:, 0] * s + local[:, 1] * c
        pu, pv = self.world_to_pixel(wx, wy, np.full(4, z))
        return np.column_stack([pu, pv])

    # ---------------------------------------------------------------- files
    def camera_info_yaml(self, camera_name: str = "overhead_camera") -> dict:
        """The standard ROS camera_info YAML (camera_calibration_parsers format)."""
        P = np.hstack([self.K, np.zeros((3, 1))])
        return {
            "image_width": int(self.width),
            "image_height": int(self.height),
            "camera_name": camera_name,
            "camera_matrix": {"rows": 3, "cols": 3, "data": self.K.ravel().tolist()},
            "distortion_model": "plumb_bob" if self.D.size <= 5 else "rational_polynomial",
            "distortion_coefficients": {"rows": 1, "cols": int(self.D.size),
                                        "data": self.D.tolist()},
            "rectification_matrix": {"rows": 3, "cols": 3, "data": np.eye(3).ravel().tolist()},
            "projection_matrix": {"rows": 3, "cols": 4, "data": P.ravel().tolist()},
        }

    def extrinsics_yaml(
        self, parent_frame: str = "world", child_frame: str = "camera_optical_frame",
        rms_px: float | None = None,
    ) -> dict:
        q = self.orientation_xyzw
        out = {
            "parent_frame": parent_frame,
            "child_frame": child_frame,
            "translation": dict(zip("xyz", (float(a) for a in self.centre), strict=True)),
            "rotation": dict(zip("xyzw", (float(a) for a in q), strict=True)),
        }
        if rms_px is not None:
            out["reprojection_rms_px"] = float(rms_px)
        return out

    def save(self, camera_info_path: Path, extrinsics_path: Path, rms_px: float | None = None,
             camera_name: str = "overhead_camera") -> None:
        Path(camera_info_path).write_text(yaml.safe_dump(self.camera_info_yaml(camera_name),
                                                         sort_keys=False))
        Path(extrinsics_path).write_text(yaml.safe_dump(self.extrinsics_yaml(rms_px=rms_px),
                                                        sort_keys=False))

    @classmethod
    def load(cls, camera_info_path: Path, extrinsics_path: Path) -> Calibration:
        K, D, w, h = load_camera_info_yaml(camera_info_path)
        pos, quat = load_extrinsics_yaml(extrinsics_path)
        return cls.from_camera_pose(K, pos, quat, w, h, D)


def load_camera_info_yaml(path: Path) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Read K, D, width, height from a standard ROS camera_info YAML."""
    data = yaml.safe_load(Path(path).read_text())
    try:
        K = np.asarray(data["camera_matrix"]["data"], dtype=np.float64).reshape(3, 3)
        D = np.asarray(data.get("distortion_coefficients", {}).get("data", [0.0] * 5), float)
        return K, D, int(data["image_width"]), int(data["image_height"])
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"{path}: not a camera_info YAML ({err})") from err


def load_extrinsics_yaml(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read the camera_optical_frame pose in world (position, quaternion xyzw)."""
    data = yaml.safe_load(Path(path).read_text())
    try:
        t, r = data["translation"], data["rotation"]
        return (np.array([t["x"], t["y"], t["z"]], dtype=float),
                np.array([r["x"], r["y"], r["z"], r["w"]], dtype=float))
    except (KeyError, TypeError) as err:
        raise ValueError(f"{path}: not an extrinsics YAML ({err})") from err


def solve_extrinsics(
    world_points: np.ndarray, pixel_points: np.ndarray, K: np.ndarray, D: np.ndarray,
    width: int, height: int,
) -> tuple[Calibration, float, np.ndarray]:
    """Camera pose from >= 4 known world points and their pixels (cv2.solvePnP).

    Returns the calibration, the RMS reprojection error in pixels and the per-point errors.
    """
    W = np.asarray(world_points, dtype=np.float64).reshape(-1, 3)
    P = np.asarray(pixel_points, dtype=np.float64).reshape(-1, 2)
    if len(W) != len(P):
        raise ValueError(f"{len(W)} world points but {len(P)} pixels")
    if len(W) < 4:
        raise ValueError(f"solvePnP needs at least 4 points, got {len(W)}")
    planar = np.ptp(W[:, 2]) < 1e-9
    flag = cv2.SOLVEPNP_IPPE if planar else cv2.SOLVEPNP_EPNP
    ok, rvec, tvec = cv2.solvePnP(W, P, K, D, flags=flag)
    if not ok:
        raise ValueError("cv2.solvePnP found no pose for these points")
    rvec, tvec = cv2.solvePnPRefineLM(W, P, K, D, rvec, tvec)
    calib = Calibration(K=K, rvec=rvec, tvec=tvec, width=width, height=height, D=D)
    err = np.linalg.norm(calib.project(W) - P, axis=1)
    return calib, float(np.sqrt(np.mean(err**2))), err
