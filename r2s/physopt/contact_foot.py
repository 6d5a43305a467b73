"""A flat foot under an object that rolls off where it was seen: a repair the camera cannot see.

An object seen at rest on its lowest point rests on a patch, not a point: fruit and soft
things flatten where they touch, and a shape completed or guessed from one image is wrong
exactly there, below, where no camera looks. A rigid round collision shape balances on one
point, so an object whose centre of mass is a few millimetres off that point rolls away in
the simulator, and the repairs that settle it carry it (and what leans on it) away from
where it was seen.

The foot: each convex piece of the object that reaches within ``height_m`` of the object's
lowest point (along the up direction) gets the slice of itself at that height projected
down onto the lowest level, and becomes the convex hull of both. The object keeps its
lowest point, so nothing is lifted or sunk; it now stands on a flat patch of about
``sqrt(2 r h)`` radius (12 mm for a 70 mm fruit at h = 2 mm), like a real one. A flat
bottom already is its own foot (the hull does not change). The visual mesh is untouched.

Frames: pieces are in their object's frame; ``world_from_object`` (4, 4); ``up`` (3,) a
unit vector in the world frame (against gravity).
"""

from __future__ import annotations

import numpy as np
import trimesh

FOOT_HEIGHT_M = 0.002
"""Default slice height above the lowest point."""


def _section_points(piece: trimesh.Trimesh, origin: np.ndarray, normal: np.ndarray
                    ) -> np.ndarray:
    """(K, 3) points where the piece's edges cross the plane (object frame)."""
    v = np.asarray(piece.vertices, dtype=np.float64)
    edges = np.asarray(piece.edges_unique)
    d = (v - origin) @ normal
    a, b = d[edges[:, 0]], d[edges[:, 1]]
    cross = (a < 0) != (b < 0)
    if not cross.any():
        return np.zeros((0, 3))
    e = edges[cross]
    t = (a[cross] / (a[cross] - b[cross]))[:, None]
    return v[e[:, 0]] + t * (v[e[:, 1]] - v[e[:, 0]])


def with_foot(pieces: list[trimesh.Trimesh], world_from_object: np.ndarray, up: np.ndarray,
              height_m: float = FOOT_HEIGHT_M) -> tuple[list[trimesh.Trimesh], float]:
    """The object's pieces with a foot (module docstring).

    Returns the new pieces (those out of reach unchanged, same objects) and the foot's
    area in m^2 (0 when no piece changed).
    """
    R = np.asarray(world_from_object, dtype=np.float64)[:3, :3]
    up_obj = R.T @ (np.asarray(up, dtype=np.float64) / np.linalg.norm(up))
    heights = [np.asarray(p.vertices) @ up_obj for p in pieces]
    low = min(float(h.min()) for h in heights)
    out, area = [], 0.0
    for piece, h in zip(pieces, heights):
        if h.min() > low + height_m or h.max() <= low + height_m:
            out.append(piece)
            continue
        section = _section_points(piece, up_obj * (low + height_m), up_obj)
        if len(section) < 3:
            out.append(piece)
            continue
        base = section - np.outer(section @ up_obj - low, up_obj)
        try:
            hull = trimesh.convex.convex_hull(np.vstack([piece.vertices, base]))
        except Exception:  # degenerate hull (qhull): keep the piece as it was
            out.append(piece)
            continue
        area += float(hull.area_faces[(hull.face_normals @ -up_obj) > 0.999].sum())
        out.append(hull)
    return out, area
