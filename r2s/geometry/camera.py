"""Pinhole camera geometry: depth pixels to world points and world points to pixels.

The camera frame is OpenCV's (x right, y down, z forward); ``world_from_camera`` (4, 4)
maps camera coordinates to world coordinates. Pixel ``(u, v)`` is column ``u``, row ``v``;
the centre of the top-left pixel is ``(0, 0)``, so pixel ``(u, v)`` with depth ``z`` is the
camera point ``z * K^-1 [u, v, 1]``. Depth is measured along the camera z axis; NaN, inf
and values <= 0 mean "no reading".
"""

from __future__ import annotations

import numpy as np


def camera_center(world_from_camera: np.ndarray) -> np.ndarray:
    """(3,) the camera's optical centre in the world frame."""
    return np.asarray(world_from_camera, dtype=np.float64)[:3, 3].copy()


def transform_points(target_from_source: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a (4, 4) transform to (N, 3) points; returns (N, 3) float64."""
    t = np.asarray(target_from_source, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return p @ t[:3, :3].T + t[:3, 3]


def backproject(depth_m: np.ndarray, K: np.ndarray, world_from_camera: np.ndarray,
                mask: np.ndarray | None = None, return_pixels: bool = False
                ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """World points of the valid depth pixels (inside ``mask`` when given).

    Parameters
    ----------
    depth_m : (H, W) float, metres along the camera z axis; NaN / inf / <= 0 = no reading.
    K : (3, 3) intrinsics, pixels.
    world_from_camera : (4, 4) OpenCV camera to world.
    mask : (H, W) bool or None; only pixels where it is True are used.
    return_pixels : also return the pixel indices.

    Returns
    -------
    points : (N, 3) float64 world points, in row-major pixel order.
    pixels : (N, 2) int64 ``(row, col)`` of each point (only when ``return_pixels``).
    """
    depth = np.asarray(depth_m, dtype=np.float64)
    valid = np.isfinite(depth) & (depth > 0)
    if mask is not None:
        valid &= np.asarray(mask, dtype=bool)
    rows, cols = np.nonzero(valid)
    pixels = np.stack([rows, cols], axis=1).astype(np.int64)
    z = depth[rows, cols]
    points = transform_points(world_from_camera, rays_per_depth(pixels, K) * z[:, None])
    if return_pixels:
        return points, pixels
    return points


def instance_points(depth_m: np.ndarray, K: np.ndarray, world_from_camera: np.ndarray,
                    masks: np.ndarray, ids: list[int], rng: np.random.Generator,
                    per_instance: int) -> list[np.ndarray]:
    """Per instance id, its observed world points: (N_k, 3), at most ``per_instance`` of
    them (drawn with ``rng`` when there are more). ``masks``: (H, W) ids."""
    out = []
    for obj_id in ids:
        pts = backproject(depth_m, K, world_from_camera, np.asarray(masks) == obj_id)
        if len(pts) > per_instance:
            pts = pts[rng.choice(len(pts), size=per_instance, replace=False)]
        out.append(pts)
    return out


def rays_per_depth(pixels: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(N, 3) camera-frame ray through each ``(row, col)`` pixel of ``pixels`` (N, 2),
    scaled to camera z = 1: the camera point at depth z is ``z * ray``."""
    k = np.asarray(K, dtype=np.float64)
    rows, cols = pixels[:, 0], pixels[:, 1]
    x = (cols - k[0, 2] - k[0, 1] * (rows - k[1, 2]) / k[1, 1]) / k[0, 0]
    y = (rows - k[1, 2]) / k[1, 1]
    return np.stack([x, y, np.ones(len(x))], axis=1)


def project(points_world: np.ndarray, K: np.ndarray, world_from_camera: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """Project world points into the image.

    Parameters
    ----------
    points_world : (N, 3) world points.
    K : (3, 3) intrinsics.
    world_from_camera : (4, 4).

    Returns
    -------
    uv : (N, 2) float64 pixel coordinates ``(u = column, v = row)``; NaN where ``z_m <= 0``.
    z_m : (N,) float64 depth along the camera z axis (negative behind the camera).
    """
    camera_from_world = np.linalg.inv(np.asarray(world_from_camera, dtype=np.float64))
    pc = transform_points(camera_from_world, points_world)
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        hom = pc @ np.asarray(K, dtype=np.float64).T
        uv = hom[:, :2] / hom[:, 2:3]
    uv[z <= 0] = np.nan
    return uv, z


def image_pixels(points_world: np.ndarray, K: np.ndarray, world_from_camera: np.ndarray,
                 height: int, width: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The pixel each world point lands on in an image of ``height`` x ``width`` pixels.

    Returns
    -------
    ok : (N,) bool, in front of the camera and inside the image.
    row, col : (N,) int64 the nearest pixel (0 where not ``ok``).
    uv : (N, 2) and z_m : (N,) as :func:`project` gives them.
    """
    uv, z = project(points_world, K, world_from_camera)
    ok = np.all(np.isfinite(uv), axis=1) & (z > 0)
    col = np.rint(np.where(ok, uv[:, 0], -1)).astype(np.int64)
    row = np.rint(np.where(ok, uv[:, 1], -1)).astype(np.int64)
    ok &= (row >= 0) & (row < height) & (col >= 0) & (col < width)
    return ok, np.where(ok, row, 0), np.where(ok, col, 0), uv, z


def pixel_rays(K: np.ndarray, world_from_camera: np.ndarray, width: int, height: int
               ) -> tuple[np.ndarray, np.ndarray]:
    """World ray of every pixel centre, for ray casting a synthetic view.

    Returns
    -------
    origins : (H, W, 3) the camera centre, repeated.
    directions : (H, W, 3) world directions scaled so that a hit at parameter ``t`` has
        camera depth ``z = t`` (the camera-frame direction has z = 1).
    """
    k_inv = np.linalg.inv(np.asarray(K, dtype=np.float64))
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    pix = np.stack([u, v, np.ones_like(u)], axis=-1)
    d_cam = pix @ k_inv.T
    rot = np.asarray(world_from_camera, dtype=np.float64)[:3, :3]
    d_world = d_cam @ rot.T
    origins = np.broadcast_to(camera_center(world_from_camera), d_world.shape).copy()
    return origins, d_world


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """(4, 4) world_from_camera of an OpenCV camera at ``eye`` looking at ``target``.

    The image's "up" (-y) is as close to ``up`` as the viewing direction allows.
    """
    eye = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, np.array([0.0, 1.0, 0.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    out = np.eye(4)
    out[:3, 0], out[:3, 1], out[:3, 2], out[:3, 3] = x, y, z, eye
    return out


def intrinsics(width: int, height: int, fov_y_deg: float) -> np.ndarray:
    """(3, 3) K of a square-pixel camera with vertical field of view ``fov_y_deg``."""
    f = 0.5 * height / np.tan(np.radians(fov_y_deg) / 2)
    return np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])
