"""Things on the table that no mask covers: a segmenter's missed objects.

A segmentation network misses objects (small, transparent, unusual, or simply not asked
for). Their pixels are mask 0, so r2s takes them as table; an object resting on one is
then completed down to the table through it, or dropped onto the table by physopt, and
nothing in the export says why. This module finds them in the observation: connected
background pixels that stand clearly above the support plane, away from every mask's
outline (where bleeding, eroded masks and flying pixels put background pixels above the
table), no taller than a tabletop object (a wall or a shelf behind the table is not
one).

Frames: the depth image is camera z-depth in metres (OpenCV camera), ``K`` (3, 3),
``world_from_camera`` (4, 4); the plane ``normal . (x - point) = 0`` in the world frame,
normal up. Pixels are ``(row, col)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import ConvexHull, QhullError

from r2s.geometry.camera import backproject
from r2s.geometry.plane import signed_distance

MIN_HEIGHT_M = 0.015
"""A background pixel this far above the support counts as standing on it (RealSense-class
noise at 1 m is about 2 mm; a warped table or a mat a few mm)."""
MAX_HEIGHT_M = 0.35
"""A region whose 95th-percentile height exceeds this is a wall, a shelf or a person, not
an object on the table."""
MARGIN_PX = 4
"""Pixels this close to any mask are left out (mask bleed and erosion, flying pixels)."""
MIN_AREA_FRACTION = 0.0015
"""Smallest region, as a fraction of the image (460 px at 640 x 480)."""
MIN_AREA_PX = 200
"""... and never fewer pixels than this."""
UNSEGMENTED_KEY = "unsegmented"
"""Scene-level key of init's state: the regions found, as dicts (``area_px``, ``box_px``,
``height_m``, ``centre_world``, ``world_from_box``, ``size_m``, ``touching_ids``,
``rests_on_it``)."""


@dataclass(frozen=True)
class UnsegmentedRegion:
    """One connected region of unmasked pixels standing above the support.

    area_px : its pixels; box_px : (row0, col0, row1, col1), inclusive;
    height_m : 95th percentile of its points' heights above the support plane;
    centre_world : (3,) mean of its points, world frame;
    touching_ids : instance ids whose masks lie within ``2 * MARGIN_PX`` of it, sorted;
    pixels : (H, W) bool, the region;
    world_from_box, size_m : (4, 4) and (3,): the box that stands on the support and holds
        the region's points (:func:`standing_box`), the least a planner should avoid.
    """

    area_px: int
    box_px: tuple[int, int, int, int]
    height_m: float
    centre_world: np.ndarray
    touching_ids: tuple[int, ...]
    pixels: np.ndarray
    world_from_box: np.ndarray
    size_m: np.ndarray

    def describe(self) -> str:
        r0, c0, r1, c1 = self.box_px
        touch = (f"; touches object{'s' if len(self.touching_ids) > 1 else ''} "
                 f"{', '.join(map(str, self.touching_ids))}") if self.touching_ids else ""
        return (f"{self.area_px} unmasked pixels (rows {r0}-{r1}, columns {c0}-{c1}) stand up "
                f"to {1000 * self.height_m:.0f} mm above the table{touch}")


def height_map_m(depth_m: np.ndarray, K: np.ndarray, world_from_camera: np.ndarray,
                 plane_point: np.ndarray, plane_normal: np.ndarray) -> np.ndarray:
    """(H, W) height of each pixel's observed point above the plane, m (NaN: no reading)."""
    points, pixels = backproject(depth_m, K, world_from_camera, return_pixels=True)
    height = np.full(np.shape(depth_m), np.nan)
    height[pixels[:, 0], pixels[:, 1]] = signed_distance(points, plane_point, plane_normal)
    return height


def unsegmented_regions(depth_m: np.ndarray, K: np.ndarray, world_from_camera: np.ndarray,
                        masks: np.ndarray, plane_point: np.ndarray, plane_normal: np.ndarray,
                        min_height_m: float = MIN_HEIGHT_M, max_height_m: float = MAX_HEIGHT_M,
                        margin_px: int = MARGIN_PX, min_area_px: int | None = None
                        ) -> list[UnsegmentedRegion]:
    """The regions of unmasked pixels that stand on or above the support, largest first.

    Parameters
    ----------
    depth_m : (H, W) camera z-depth, m; masks : (H, W) instance ids (0: none).
    K, world_from_camera : the camera; plane_point, plane_normal : the support plane.
    min_height_m, max_height_m, margin_px : see the module constants.
    min_area_px : smallest region; default ``max(MIN_AREA_PX, MIN_AREA_FRACTION * H * W)``.
    """
    masks = np.asarray(masks)
    h, w = masks.shape
    if min_area_px is None:
        min_area_px = max(MIN_AREA_PX, int(MIN_AREA_FRACTION * h * w))
    height = height_map_m(depth_m, K, world_from_camera, plane_point, plane_normal)
    near_mask = ndimage.binary_dilation(masks > 0, iterations=margin_px) \
        if margin_px > 0 else masks > 0
    with np.errstate(invalid="ignore"):
        above = (masks == 0) & ~near_mask & (height > min_height_m)
    labels, count = ndimage.label(above, structure=np.ones((3, 3), dtype=bool))
    if count == 0:
        return []
    areas = np.bincount(labels.ravel(), minlength=count + 1)
    out = []
    for lab in np.flatnonzero(areas >= min_area_px):
        if lab == 0:
            continue
        region = labels == lab
        heights = height[region]
        top = float(np.percentile(heights, 95))
        if top > max_height_m:
            continue
        rows, cols = np.nonzero(region)
        ring = ndimage.binary_dilation(region, iterations=2 * margin_px) & (masks > 0)
        touching = tuple(sorted(int(i) for i in np.unique(masks[ring])))
        points = backproject(depth_m, K, world_from_camera, region)
        box, size = standing_box(points, plane_point, plane_normal)
        out.append(UnsegmentedRegion(int(region.sum()), (int(rows.min()), int(cols.min()),
                                                         int(rows.max()), int(cols.max())),
                                     top, points.mean(axis=0), touching, region, box, size))
    return sorted(out, key=lambda r: -r.area_px)


def standing_box(points: np.ndarray, plane_point: np.ndarray, plane_normal: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The box that stands on the plane and holds (N, 3) world ``points`` (1st to 99th
    percentile across, up to the 99th of the heights), turned about the normal as the
    least-area rectangle around the points' footprint.

    Returns ``world_from_box`` (4, 4), the box frame at its centre with z along the normal,
    and ``size_m`` (3,). Only what the camera saw: the side facing away may reach farther."""
    n = np.asarray(plane_normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    rel = np.asarray(points, dtype=np.float64) - np.asarray(plane_point, dtype=np.float64)
    axis = _least_area_direction(np.stack([rel @ u, rel @ v], axis=1))
    a = axis[0] * u + axis[1] * v
    b = np.cross(n, a)
    lo_a, hi_a = np.percentile(rel @ a, [1, 99])
    lo_b, hi_b = np.percentile(rel @ b, [1, 99])
    top = max(float(np.percentile(rel @ n, 99)), 1e-3)
    T = np.eye(4)
    T[:3, :3] = np.stack([a, b, n], axis=1)
    T[:3, 3] = (np.asarray(plane_point, dtype=np.float64) + a * (lo_a + hi_a) / 2
                + b * (lo_b + hi_b) / 2 + n * top / 2)
    return T, np.array([hi_a - lo_a, hi_b - lo_b, top])


def _least_area_direction(uv: np.ndarray) -> np.ndarray:
    """(2,) unit direction of one side of the least-area rectangle holding the (N, 2)
    points (one side of it lies along an edge of their convex hull)."""
    try:
        hull = uv[ConvexHull(uv).vertices]
    except (QhullError, ValueError):  # collinear or too few points
        return np.array([1.0, 0.0])
    edges = np.roll(hull, -1, axis=0) - hull
    dirs = edges / np.maximum(np.linalg.norm(edges, axis=1, keepdims=True), 1e-12)
    along = hull @ dirs.T  # (hull points, directions)
    across = hull @ np.stack([-dirs[:, 1], dirs[:, 0]], axis=1).T
    area = np.ptp(along, axis=0) * np.ptp(across, axis=0)
    return dirs[int(np.argmin(area))]
