"""Mask pixels the depth sensor left empty, given the depth of the object's nearest reading.

A RealSense-class sensor reads no depth on dark, glossy and thin surfaces and in a band
along depth edges, which is where an object's outline is (docs/realistic.md). A shape
completed from the depth points alone then has a footprint smaller than what the mask
shows: the outline and the dark parts of its top are missing. Here each pixel of the
object's mask that has no valid reading and lies within ``radius_px`` pixels of one of the
object's kept points (after point cleanup, so bleed onto the table or onto a neighbour is
never a source) takes the depth (camera z) of the nearest such pixel and is
back-projected. A pixel farther from every kept point stays empty: a whole part of the mask
without depth is not guessed. Nor is a pixel within ``neighbour_gap_px`` of another
object's mask: a segmenter's mask bleeds onto a touching neighbour, whose edge pixels read
no depth as often as any, and filling them would grow the object into its neighbour.

With the support plane's up direction given (``up``), a pixel whose ray passes *above*
its nearest reading at that reading's depth takes the depth where the ray comes down to
the reading's height above the plane instead: the surface continues behind at the same
height. That is the top of a silhouette seen obliquely: the grazing top and back of a ball, a can or a
bottle read no depth, and the nearest reading's depth would make the object taller
where it is deeper. A pixel whose ray passes below (the lower outline) or level keeps the
nearest reading's depth, so the rule only ever moves a point away from the camera, never
by more than the ray's fall to that height.

Frames: pixels are ``(row, col)``; depth is metres along the camera's z axis (OpenCV
camera: x right, y down, z forward); points are in the world frame of ``world_from_camera``.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from r2s.geometry.camera import backproject, rays_per_depth

FILL_RADIUS_PX = 6
"""Default reach of a kept reading into the empty mask pixels around it (pixels)."""

NEIGHBOUR_GAP_PX = 4
"""Empty pixels this close to another object's mask stay empty (the widest bleed of the
realistic benchmark's segmenter model is 4 px)."""


def fill_mask_holes(mask: np.ndarray, depth_m: np.ndarray, kept_pixels: np.ndarray,
                    K: np.ndarray, world_from_camera: np.ndarray,
                    radius_px: float = FILL_RADIUS_PX, others: np.ndarray | None = None,
                    neighbour_gap_px: float = NEIGHBOUR_GAP_PX,
                    up: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Points for the object's mask pixels that have no depth reading.

    Parameters
    ----------
    mask : (H, W) bool, the object's instance mask.
    depth_m : (H, W) float depth image, metres; NaN / inf / <= 0 = no reading.
    kept_pixels : (N, 2) int ``(row, col)`` of the object's points that were kept (each has
        a valid reading).
    K : (3, 3) intrinsics, pixels; world_from_camera : (4, 4) camera to world.
    radius_px : largest image distance (pixels) from an empty pixel to the kept pixel whose
        depth it takes; <= 0 fills nothing.
    others : (H, W) bool, the other objects' masks, or None; empty pixels within
        ``neighbour_gap_px`` (Euclidean) of them are not filled.
    up : (3,) unit normal of the support plane (world frame, pointing up, towards the
        camera's side), or None. Given, a pixel whose ray at its nearest reading's depth
        lies above that reading's height takes the (larger) depth where the ray reaches
        that height (see the module's docstring). Heights need only the plane's direction.

    Returns
    -------
    points : (M, 3) world points of the filled pixels; pixels : (M, 2) their ``(row, col)``.
    """
    depth = np.asarray(depth_m, dtype=np.float64)
    kept = np.asarray(kept_pixels, dtype=np.int64).reshape(-1, 2)
    empty_rows = np.zeros((0, 3)), np.zeros((0, 2), dtype=np.int64)
    if radius_px <= 0 or len(kept) == 0:
        return empty_rows
    valid = np.isfinite(depth) & (depth > 0)
    empty = np.asarray(mask, dtype=bool) & ~valid
    if others is not None and np.any(others):
        empty &= ndimage.distance_transform_edt(~np.asarray(others, dtype=bool)) > neighbour_gap_px
    holes = np.argwhere(empty)
    if len(holes) == 0:
        return empty_rows
    # the bound is strict; a hair over it makes ``radius_px`` itself count
    dist, nearest = cKDTree(kept).query(holes, distance_upper_bound=float(radius_px) + 1e-6)
    reached = np.isfinite(dist)
    holes, nearest = holes[reached], nearest[reached]
    z = depth[kept[nearest, 0], kept[nearest, 1]]
    if up is not None:
        z = _continued_at_height(z, holes, kept[nearest], K, world_from_camera, up)
    filled = np.zeros_like(depth)
    filled[holes[:, 0], holes[:, 1]] = z
    return backproject(filled, K, world_from_camera, return_pixels=True)


def _continued_at_height(z_nearest: np.ndarray, holes: np.ndarray, sources: np.ndarray,
                         K: np.ndarray, world_from_camera: np.ndarray, up: np.ndarray
                         ) -> np.ndarray:
    """(N,) depth (camera z, m) of each hole: ``max(z_nearest, z at the source's height)``.

    ``holes`` and ``sources`` are (N, 2) ``(row, col)``: each hole and the kept pixel whose
    depth ``z_nearest`` (N,) it takes. A point at depth z on pixel p's ray lies
    ``z * up . ray(p)`` above the camera (``ray`` in the world frame, camera z = 1), so the
    hole's ray reaches the source's height at
    ``z_nearest * up . ray(source) / up . ray(hole)``; the plane's offset cancels.
    """
    R = np.asarray(world_from_camera, dtype=np.float64)[:3, :3]
    up = np.asarray(up, dtype=np.float64)
    source_up = (rays_per_depth(sources, K) @ R.T) @ up
    hole_up = (rays_per_depth(holes, K) @ R.T) @ up
    with np.errstate(divide="ignore", invalid="ignore"):
        z_level = z_nearest * source_up / hole_up
    # only a ray falling towards the plane (hole_up < 0) reaches the height behind
    deeper = (hole_up < 0) & np.isfinite(z_level) & (z_level > z_nearest)
    return np.where(deeper, z_level, z_nearest)
