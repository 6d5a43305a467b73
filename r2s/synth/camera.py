"""Pinhole camera placement and the conversions to and from PyBullet's OpenGL camera.

Frames: ``world_from_camera`` is the OpenCV camera (x right, y down, z forward). PyBullet's
software renderer takes an OpenGL view matrix (x right, y up, z backward) and a symmetric
OpenGL projection; it samples pixel ``(c, r)`` at OpenGL window position ``(c, H - 1 - r)``
with no half-pixel offset, so in OpenCV pixel coordinates its principal point is
``(W / 2, H / 2 - 1)`` (measured against analytic depth of a tilted plane to 1e-6 m).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

NEAR_M = 0.05
FAR_M = 10.0

_CV_FROM_GL = np.diag([1.0, -1.0, -1.0, 1.0])


def intrinsics(width: int, height: int, vfov_deg: float) -> np.ndarray:
    """(3, 3) K of PyBullet's renderer for a vertical field of view, square pixels."""
    fy = (height / 2.0) / np.tan(np.radians(vfov_deg) / 2.0)
    return np.array([[fy, 0.0, width / 2.0], [0.0, fy, height / 2.0 - 1.0], [0.0, 0.0, 1.0]])


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, 0.0, 1.0])
            ) -> np.ndarray:
    """(4, 4) world_from_camera (OpenCV) of a camera at ``eye`` looking at ``target``."""
    z = np.asarray(target, dtype=float) - np.asarray(eye, dtype=float)
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, y, z, eye
    return pose


def orbit_pose(target: np.ndarray, elevation_deg: float, azimuth_deg: float,
               distance_m: float, roll_deg: float = 0.0) -> np.ndarray:
    """world_from_camera of a camera on a sphere around ``target`` looking at it.

    ``elevation_deg`` is the angle of the line of sight below the horizontal; ``roll_deg``
    turns the camera about its line of sight (positive: its x axis towards its y axis,
    clockwise as seen from behind it, so the scene turns counter-clockwise in the image);
    0 keeps the image's x axis level.
    """
    el, az = np.radians(elevation_deg), np.radians(azimuth_deg)
    offset = distance_m * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az),
                                    np.sin(el)])
    pose = look_at(np.asarray(target, dtype=float) + offset, target)
    if roll_deg:
        pose[:3, :3] = pose[:3, :3] @ Rotation.from_euler("z", roll_deg, degrees=True).as_matrix()
    return pose


def fit_distance(points: np.ndarray, target: np.ndarray, elevation_deg: float,
                 azimuth_deg: float, K: np.ndarray, width: int, height: int,
                 margin_px: float, roll_deg: float = 0.0) -> float:
    """Smallest camera distance at which every point projects ``margin_px`` inside the image."""
    lo, hi = 0.05, 5.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        uv, z = project(points, K, orbit_pose(target, elevation_deg, azimuth_deg, mid, roll_deg))
        inside = np.all(z > NEAR_M) and np.all(
            (uv[:, 0] >= margin_px) & (uv[:, 0] <= width - 1 - margin_px)
            & (uv[:, 1] >= margin_px) & (uv[:, 1] <= height - 1 - margin_px))
        lo, hi = (lo, mid) if inside else (mid, hi)
    return hi


def project(points_world: np.ndarray, K: np.ndarray, world_from_camera: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (N, 2) (OpenCV, pixel centres at integers) and depths (N,) in m."""
    camera_from_world = np.linalg.inv(world_from_camera)
    pts = np.asarray(points_world, dtype=float) @ camera_from_world[:3, :3].T \
        + camera_from_world[:3, 3]
    z = pts[:, 2]
    uv = (pts @ np.asarray(K).T)[:, :2] / np.where(np.abs(z) < 1e-12, 1e-12, z)[:, None]
    return uv, z


def gl_view_matrix(world_from_camera: np.ndarray) -> list[float]:
    """PyBullet ``viewMatrix`` (16 floats, column-major) of an OpenCV world_from_camera."""
    view = _CV_FROM_GL @ np.linalg.inv(world_from_camera)
    return [float(v) for v in view.T.reshape(-1)]


def gl_projection_matrix(K: np.ndarray, width: int, height: int, near_m: float = NEAR_M,
                         far_m: float = FAR_M) -> list[float]:
    """PyBullet ``projectionMatrix`` (16 floats, column-major) for :func:`intrinsics`."""
    fx, fy = K[0, 0], K[1, 1]
    proj = np.array([
        [2.0 * fx / width, 0.0, 0.0, 0.0],
        [0.0, 2.0 * fy / height, 0.0, 0.0],
        [0.0, 0.0, -(far_m + near_m) / (far_m - near_m), -2.0 * far_m * near_m / (far_m - near_m)],
        [0.0, 0.0, -1.0, 0.0],
    ])
    return [float(v) for v in proj.T.reshape(-1)]


def depth_from_gl_buffer(buffer: np.ndarray, near_m: float = NEAR_M, far_m: float = FAR_M
                         ) -> np.ndarray:
    """Metric depth along the camera z axis (H, W) from an OpenGL depth buffer in [0, 1].

    Pixels at the far plane (no geometry) become NaN.
    """
    buf = np.asarray(buffer, dtype=np.float64)
    depth = far_m * near_m / (far_m - (far_m - near_m) * buf)
    depth[buf >= 1.0 - 1e-7] = np.nan
    return depth


def rotated_about_centre(world_from_camera: np.ndarray, axis: np.ndarray, angle_deg: float
                         ) -> np.ndarray:
    """The camera turned by ``angle_deg`` about the world ``axis`` through its centre."""
    rot = Rotation.from_rotvec(np.radians(angle_deg) * np.asarray(axis) / np.linalg.norm(axis))
    out = np.array(world_from_camera, dtype=float)
    out[:3, :3] = rot.as_matrix() @ out[:3, :3]
    return out


def random_unit_vector(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)
