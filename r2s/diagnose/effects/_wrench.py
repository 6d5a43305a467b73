"""Static balance of a resting object: where must its centre of mass be?

A rigid object resting on contacts under gravity is in balance only if the line of
gravity through its centre of mass passes through the convex hull of its support contacts
(projected along gravity). The smallest COM shift that restores balance moves the COM's
projection to the nearest point of that hull (a little inside it for an area contact;
exactly onto a point or line contact, where balance pins it).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from r2s.diagnose.stats.blocks import tangent_frame


def _nearest_on_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = float(np.clip((p - a) @ ab / max(ab @ ab, 1e-18), 0.0, 1.0))
    return a + t * ab


def nearest_in_hull_2d(points: np.ndarray, p: np.ndarray, margin_m: float = 0.0,
                       collinear_tol_m: float = 1e-3) -> tuple[np.ndarray, bool]:
    """Nearest point to ``p`` in the convex hull of (M, 2) ``points``, and whether ``p``
    was inside already.

    An area hull's answer is moved ``margin_m`` towards the hull's centroid (at most to
    it); a point or a segment (all points within ``collinear_tol_m`` of a line) is used
    as is.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    p = np.asarray(p, dtype=np.float64)
    if len(pts) == 0:
        raise ValueError("no support contact")
    centre = pts.mean(axis=0)
    spread = pts - centre
    if len(pts) == 1 or np.linalg.norm(spread, axis=1).max() < collinear_tol_m:
        return centre, bool(np.linalg.norm(p - centre) < collinear_tol_m)
    _, sv, vt = np.linalg.svd(spread, full_matrices=False)
    width = np.abs(spread @ vt[1]).max() if len(sv) > 1 else 0.0
    if width < collinear_tol_m:  # a line contact
        s = spread @ vt[0]
        a, b = centre + s.min() * vt[0], centre + s.max() * vt[0]
        q = _nearest_on_segment(p, a, b)
        return q, bool(np.linalg.norm(p - q) < collinear_tol_m)
    try:
        hull = ConvexHull(pts)
    except QhullError:
        return centre, False
    eq = hull.equations  # (F, 3): n . x + d <= 0 inside
    if np.all(eq[:, :2] @ p + eq[:, 2] <= 0.0):
        return p.copy(), True
    best, best_d = None, np.inf
    verts = pts[hull.vertices]
    for k in range(len(verts)):
        q = _nearest_on_segment(p, verts[k], verts[(k + 1) % len(verts)])
        d = np.linalg.norm(q - p)
        if d < best_d:
            best, best_d = q, d
    inward = pts[hull.vertices].mean(axis=0) - best
    dist = np.linalg.norm(inward)
    if dist > 1e-12 and margin_m > 0:
        best = best + inward / dist * min(margin_m, dist)
    return best, False


def balancing_com_shift(com_world: np.ndarray, contacts_world: np.ndarray,
                        gravity: np.ndarray, margin_m: float = 0.002) -> np.ndarray:
    """(3,) the smallest shift, orthogonal to gravity, that puts the COM over its support.

    Parameters
    ----------
    com_world : (3,) current centre of mass.
    contacts_world : (M, 3) support contact points of the object, M >= 1.
    gravity : (3,) gravity vector.
    margin_m : how far inside an area contact to put the COM.

    Returns zeros when the COM is over its support already.
    """
    up = -np.asarray(gravity, dtype=np.float64)
    e1, e2 = tangent_frame(up)
    basis = np.stack([e1, e2])                     # (2, 3)
    c2 = basis @ np.asarray(com_world, dtype=np.float64)
    p2 = np.asarray(contacts_world, dtype=np.float64).reshape(-1, 3) @ basis.T
    q2, inside = nearest_in_hull_2d(p2, c2, margin_m)
    if inside:
        return np.zeros(3)
    return (q2 - c2) @ basis


def toppling_direction(rotation_rad: np.ndarray, gravity: np.ndarray) -> np.ndarray:
    """(3,) unit direction to move the COM to stop a rotation ``rotation_rad`` (3,).

    Gravity's torque about the support, ``(c - p) x m g``, turns the object about
    ``omega``; the COM sits on the side ``g x omega`` of its support, so moving it along
    ``omega x g`` (horizontal) stops the turn. Zeros for a rotation about gravity.
    """
    d = np.cross(np.asarray(rotation_rad, dtype=np.float64), np.asarray(gravity, dtype=np.float64))
    n = np.linalg.norm(d)
    return d / n if n > 1e-12 else np.zeros(3)
