"""The table's shape as the depth image sees it: how far its points lie from one plane.

A real table is flat to a millimetre over the image; the back-projected table pixels of a
sensor with an unmodelled error are not: radial lens distortion bends them into a bowl
(or a dome), a depth error that depends on the image row into a gutter, a colour-dependent
depth bias into a pattern that follows the tablecloth. This module fits one plane to the
table points (camera frame, trimmed least squares) and averages the point-to-plane
distances over a grid of image tiles: the tile means are the residual block that such
effects explain (:func:`r2s.diagnose.stats.blocks.table_shape_block`) and the data of the generic
residual model (:mod:`r2s.diagnose.stats.structure_test`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from r2s.geometry.plane import least_squares_plane

GRID = (8, 6)
"""Tiles across and down the image."""
MIN_TILE_POINTS = 30
TRIM_M = 0.02
"""Points farther than this from the plane (the floor beyond the table, a mask that bled)
are left out of the fit and of the tiles."""


@dataclass(frozen=True)
class TableTiles:
    """Tile means of the table points' distance to their plane.

    mean_m : (T,) signed mean distance (towards the camera positive), metres.
    count : (T,) points per tile; centre_px : (T, 2) mean (u, v) of the tile's points;
    feature : name -> (T,) tile mean of each generic feature (see :func:`point_features`).
    normal : (3,) plane normal, camera frame, pointing at the camera.
    """

    mean_m: np.ndarray
    count: np.ndarray
    centre_px: np.ndarray
    feature: dict
    normal: np.ndarray


def fit_plane(points: np.ndarray, iterations: int = 3) -> tuple[np.ndarray, float, np.ndarray]:
    """Trimmed least-squares plane ``n . p = d`` of (N, 3) points: ``(n, d, inliers)``,
    ``n`` pointing at the origin (the camera)."""
    p = np.asarray(points, dtype=np.float64)
    keep = np.ones(len(p), dtype=bool)
    n, d = np.array([0.0, 0.0, -1.0]), 0.0
    for _ in range(iterations):
        c, n = least_squares_plane(p[keep])
        if n @ c > 0:
            n = -n
        d = float(n @ c)
        dist = p @ n - d
        limit = max(TRIM_M, 0.0)
        new = np.abs(dist) <= limit
        if new.sum() < 10 or np.array_equal(new, keep):
            break
        keep = new
    return n, d, keep


def point_features(points: np.ndarray, K: np.ndarray, width: int, height: int,
                   normal: np.ndarray, gray: np.ndarray | None) -> dict:
    """Generic features of each (N, 3) camera-frame point: image column and row (-1..1
    across the image), squared radius from the principal point (normalised coordinates),
    depth (m), the cosine between its view ray and the surface normal, and grey level
    (0..1, when the image is given)."""
    p = np.asarray(points, dtype=np.float64)
    K = np.asarray(K, dtype=np.float64)
    x = p[:, 0] / p[:, 2]
    y = p[:, 1] / p[:, 2]
    u = K[0, 0] * x + K[0, 2]
    v = K[1, 1] * y + K[1, 2]
    rays = p / np.linalg.norm(p, axis=1, keepdims=True)
    out = {"column": 2.0 * u / max(width - 1, 1) - 1.0, "row": 2.0 * v / max(height - 1, 1) - 1.0,
           "radius2": x * x + y * y, "depth": p[:, 2],
           "view_cosine": np.abs(rays @ np.asarray(normal, dtype=np.float64))}
    if gray is not None:
        out["grey"] = np.asarray(gray, dtype=np.float64)
    return out


def table_tiles(points: np.ndarray, K: np.ndarray, width: int, height: int,
                gray: np.ndarray | None = None, grid: tuple[int, int] = GRID) -> TableTiles:
    """Fit the plane to ``points`` (N, 3, camera frame) and average over image tiles."""
    p = np.asarray(points, dtype=np.float64)
    n, d, keep = fit_plane(p)
    dist = (p @ n - d)[keep]
    feats = point_features(p[keep], K, width, height, n,
                           None if gray is None else np.asarray(gray)[keep])
    u = (feats["column"] + 1.0) / 2.0 * (width - 1)
    v = (feats["row"] + 1.0) / 2.0 * (height - 1)
    col = np.clip((u / width * grid[0]).astype(int), 0, grid[0] - 1)
    row = np.clip((v / height * grid[1]).astype(int), 0, grid[1] - 1)
    tile = row * grid[0] + col
    means, counts, centres = [], [], []
    fmeans: dict = {k: [] for k in feats}
    for t in range(grid[0] * grid[1]):
        sel = tile == t
        if sel.sum() < MIN_TILE_POINTS:
            continue
        means.append(float(np.mean(dist[sel])))
        counts.append(int(sel.sum()))
        centres.append((float(np.mean(u[sel])), float(np.mean(v[sel]))))
        for k, f in feats.items():
            fmeans[k].append(float(np.mean(f[sel])))
    return TableTiles(np.asarray(means), np.asarray(counts, dtype=np.int64),
                      np.asarray(centres).reshape(-1, 2),
                      {k: np.asarray(v) for k, v in fmeans.items()}, n)
