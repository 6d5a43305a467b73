"""Small 2-D convex polygon helpers on numpy arrays (support polygons, footprints).

Polygons are (K, 2) float arrays of vertices in counter-clockwise order, not closed
(the last vertex is not repeated). Degenerate hulls (a point, a segment) are allowed.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError


def convex_hull_2d(points: np.ndarray) -> np.ndarray:
    """Counter-clockwise convex hull (K, 2) of (N, 2) points (K may be 1 or 2 if degenerate)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    unique = np.unique(np.round(points, 9), axis=0)
    if len(unique) < 3:
        return unique
    try:
        hull = ConvexHull(unique)
    except QhullError:  # collinear
        d = unique - unique.mean(axis=0)
        axis = np.linalg.svd(d, full_matrices=False)[2][0]
        proj = d @ axis
        return unique[[int(np.argmin(proj)), int(np.argmax(proj))]]
    return unique[hull.vertices]  # scipy returns 2-D hulls counter-clockwise


def polygon_area(poly: np.ndarray) -> float:
    """Area of a simple polygon (K, 2) (shoelace; 0 for degenerate ones)."""
    if len(poly) < 3:
        return 0.0
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def _segments_distance(poly: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N,) distance from points to the polygon's boundary (or to a point / segment)."""
    if len(poly) == 1:
        return np.linalg.norm(points - poly[0], axis=1)
    a = poly
    b = np.roll(poly, -1, axis=0) if len(poly) > 2 else poly[::-1]
    ab = b - a  # (K, 2)
    ap = points[:, None, :] - a[None]  # (N, K, 2)
    denom = np.maximum((ab * ab).sum(-1), 1e-30)
    t = np.clip((ap * ab[None]).sum(-1) / denom, 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(points[:, None, :] - closest, axis=-1).min(axis=1)


def contains(poly: np.ndarray, points: np.ndarray, tol: float = 1e-12) -> np.ndarray:
    """(N,) bool: points inside or on a counter-clockwise convex polygon."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(poly) < 3:
        return _segments_distance(poly, points) <= max(tol, 1e-9)
    edge = np.roll(poly, -1, axis=0) - poly
    rel = points[:, None, :] - poly[None]
    cross = edge[None, :, 0] * rel[..., 1] - edge[None, :, 1] * rel[..., 0]
    return np.all(cross >= -tol, axis=1)


def distance_to_polygon(poly: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N,) distance from points to a convex polygon's area: 0 inside, else to its edge."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    d = _segments_distance(poly, points)
    if len(poly) >= 3:
        d = np.where(contains(poly, points), 0.0, d)
    return d


def convex_overlap(a: np.ndarray, b: np.ndarray, tol: float = 0.0) -> bool:
    """Whether two convex polygons overlap (separating axis test; touching counts if tol>0).

    ``tol`` is a distance: polygons closer than ``tol`` count as overlapping.
    """
    for poly in (a, b):
        if len(poly) < 2:
            continue
        edges = np.roll(poly, -1, axis=0) - poly
        normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
        norms = np.linalg.norm(normals, axis=1)
        normals = normals[norms > 1e-15] / norms[norms > 1e-15, None]
        for n in normals:
            pa, pb = a @ n, b @ n
            if pa.max() + tol < pb.min() or pb.max() + tol < pa.min():
                return False
    if len(a) < 3 and len(b) < 3:  # two points/segments: fall back to their distance
        return bool(min(_segments_distance(a, b).min(), _segments_distance(b, a).min()) <= tol)
    return True
