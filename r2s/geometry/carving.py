"""Space the camera saw through, for carving a completed shape.

A point of a completed object that projects to a pixel with a valid depth reading and lies
in front of that reading by more than a margin hides nothing the camera saw only if the
pixel is the object's own: anywhere else the camera looked *past* it (onto the table, the
wall, or an object behind), so it is free space and may not be material. Pixels with no
reading (holes) and points outside the image or behind the camera are unknown: hidden
parts may go there, as they may behind nearer objects (the reading is nearer than the
point) and below the visible surface along the ray.

The margin grows with depth like the axial noise of structured-light and stereo sensors:
``margin_m + margin_quadratic_m * (z / 1 m)^2``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from r2s.geometry.camera import project

CARVE_MARGIN_M = 0.006
CARVE_MARGIN_QUADRATIC_M = 0.006
OWN_BAND_PX = 2


@dataclass(frozen=True)
class CarveView:
    """One depth view and the pixels that are the object's own.

    K : (3, 3); world_from_camera : (4, 4) OpenCV camera; depth_m : (H, W) metres along
    the camera z axis, NaN / <= 0 = no reading; own : (H, W) bool, pixels the object may
    cover (its kept mask pixels grown by a band); margin_m, margin_quadratic_m : see the
    module docstring.
    """

    K: np.ndarray
    world_from_camera: np.ndarray
    depth_m: np.ndarray
    own: np.ndarray
    margin_m: float = CARVE_MARGIN_M
    margin_quadratic_m: float = CARVE_MARGIN_QUADRATIC_M


def carve_view(K: np.ndarray, world_from_camera: np.ndarray, depth_m: np.ndarray,
               own_pixels: np.ndarray, band_px: int = OWN_BAND_PX,
               margin_m: float = CARVE_MARGIN_M,
               margin_quadratic_m: float = CARVE_MARGIN_QUADRATIC_M) -> CarveView:
    """A :class:`CarveView` whose own pixels are ``own_pixels`` ((N, 2) int (row, col), the
    object's kept observations) grown by ``band_px`` pixels (mask edges are uncertain)."""
    depth = np.asarray(depth_m, dtype=np.float64)
    own = np.zeros(depth.shape, dtype=bool)
    pix = np.asarray(own_pixels, dtype=np.int64).reshape(-1, 2)
    own[pix[:, 0], pix[:, 1]] = True
    if band_px > 0:
        own = ndimage.binary_dilation(own, iterations=int(band_px))
    return CarveView(K=np.asarray(K, dtype=np.float64),
                     world_from_camera=np.asarray(world_from_camera, dtype=np.float64),
                     depth_m=depth, own=own, margin_m=float(margin_m),
                     margin_quadratic_m=float(margin_quadratic_m))


def seen_free(view: CarveView, points_world: np.ndarray) -> np.ndarray:
    """(N,) bool: which world points (N, 3) the camera saw past (free space)."""
    pts = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    uv, z = project(pts, view.K, view.world_from_camera)
    height, width = view.depth_m.shape
    ok = np.all(np.isfinite(uv), axis=1) & (z > 0)
    col = np.rint(np.where(ok, uv[:, 0], -1)).astype(np.int64)
    row = np.rint(np.where(ok, uv[:, 1], -1)).astype(np.int64)
    ok &= (row >= 0) & (row < height) & (col >= 0) & (col < width)
    row, col = np.where(ok, row, 0), np.where(ok, col, 0)
    d = view.depth_m[row, col]
    valid = ok & np.isfinite(d) & (d > 0) & ~view.own[row, col]
    margin = view.margin_m + view.margin_quadratic_m * np.square(np.where(valid, d, 0.0))
    with np.errstate(invalid="ignore"):
        return valid & (z < d - margin)
