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

from r2s.geometry.collision_trim import capped_hull
from r2s.physopt.piece_overlap import plane_crossings

FOOT_HEIGHT_M = 0.002
"""Default slice height above the lowest point."""


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
        section = plane_crossings(piece, h - (low + height_m))
        base = section - np.outer(section @ up_obj - low, up_obj)
        points = np.vstack([piece.vertices, base])
        # not capped: the disc's corners would be the first dropped (they hold little volume)
        hull = capped_hull(points, max_vertices=len(points)) if len(section) >= 3 else None
        if hull is None:  # degenerate: keep the piece as it was
            out.append(piece)
            continue
        area += float(hull.area_faces[(hull.face_normals @ -up_obj) > 0.999].sum())
        out.append(hull)
    return out, area
