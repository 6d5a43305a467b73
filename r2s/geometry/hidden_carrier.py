"""The hidden top of an object that carries another one over it.

An object lying on another can hide that one's whole top: a block on a foam brick, a cup
on a standing can, seen from 40-60 deg above the table. Then the camera sees only the
carrier's front face, and a completion from the observation (a height field over the
table) is a slab as thin as that face; the carried object, whose underside nobody sees,
reaches down to the table behind the slab. Both are wrong, and both topple.

The observation still tells which object carries which. The carried object's lowest
visible points touch the carrier's highest ones (they are the same edge, seen from both
sides of the masks' boundary), they lie above it, and the carried object reaches farther
from the camera than the carrier's visible face. A carrier that shows no top of its own
(its points span, along the view, much less than its height) then gets a *hidden top*:
points at its top's height over the part of the carried object's footprint behind its
visible face, across the view no wider than the carrier was seen. Completed with them, the
carrier becomes a box under the carried object; the carried object then stands on those
points (they are what it stands on for :func:`r2s.geometry.completion.complete_from_points`)
instead of reaching the table. Carving against the depth image still removes any of it
the camera saw past.

Frames: points are world (3-D); the tests run in the support plane's frame (z up from
the table), with "along" the horizontal direction from the camera to the carrier's points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay, QhullError, cKDTree

from r2s.geometry.camera import transform_points
from r2s.geometry.completion import drop_isolated
from r2s.geometry.plane import world_from_plane

TABLE_BAND_M = 0.006
"""Points lower than this over the table are left out (bleed of a mask onto the table)."""
MIN_POINTS = 30
TOP_PERCENTILE = 98.0
"""The carrier's top height: this percentile of its points' heights (robust to a few
flying pixels)."""
EDGE_BAND_M = 0.004
"""The carrier's top edge: its points within this of the top height."""
CONTACT_M = 0.006
"""A carried object's point within this (3-D) of the carrier's top edge touches it."""
MIN_CONTACT_POINTS = 10
ABOVE_TOLERANCE_M = 0.005
"""The carried object's lowest points (5th percentile) lie no lower than the carrier's top
minus this: it rests on the top, it is not beside the carrier."""
MAX_THICKNESS_RATIO = 0.6
"""The carrier shows no top when its points span along the view (5th to 95th percentile)
less than this times its height: a face, not a box seen from above."""
FAR_PERCENTILE = 98.0
"""The hidden top reaches no farther from the camera than this percentile of the carried
object's points along the view."""
MIN_BEYOND_M = 0.01
"""The carried object reaches at least this much farther from the camera (90th
percentile along the view) than the carrier's visible face (95th)."""


@dataclass(frozen=True)
class HiddenTop:
    """A carrier's hidden top under what it carries.

    carrier_id, carried_id : instance ids; height_m : the top's height over the table (m);
    points_world : (M, 3) points on that top, world frame, on a grid of the given cell.
    """

    carrier_id: int
    carried_id: int
    height_m: float
    points_world: np.ndarray

    def support_world(self, carrier_points_world: np.ndarray, plane_point: np.ndarray,
                      plane_normal: np.ndarray) -> np.ndarray:
        """(K, 3) what the carried object stands on: the hidden top and the carrier's own
        points within ``EDGE_BAND_M`` of its height (world frame, ``carrier_points_world``
        (N, 3)). The carrier's face below is left out: fitted with the top it would tilt
        the carried object's base down towards the camera."""
        pts = np.asarray(carrier_points_world, dtype=np.float64).reshape(-1, 3)
        normal = np.asarray(plane_normal, dtype=np.float64)
        normal = normal / np.linalg.norm(normal)
        height = (pts - np.asarray(plane_point, dtype=np.float64)) @ normal
        return np.concatenate([pts[height >= self.height_m - EDGE_BAND_M], self.points_world])


def hidden_tops(points_world: dict[int, np.ndarray], plane_point: np.ndarray,
                plane_normal: np.ndarray, eye_world: np.ndarray, cell_m: float = 0.003,
                carriers: set[int] | None = None) -> dict[int, HiddenTop]:
    """Per carrier id, the hidden top under the object it carries (module docstring).

    points_world : id -> (N, 3) each object's observed points, world frame; plane_point,
    plane_normal : (3,) the support plane (normal up); eye_world : (3,) the camera centre;
    cell_m : spacing of the top's points; carriers : the ids that may get a hidden top
    (None: any; an object with a registered prior keeps its shape). When an object would
    carry several, the one whose footprint adds most points is kept.
    """
    world_from_pl = world_from_plane(plane_point, plane_normal)
    plane_from_world = np.linalg.inv(world_from_pl)
    eye = transform_points(plane_from_world, np.asarray(eye_world, dtype=np.float64)[None])[0]
    local = {}
    for i, p in points_world.items():
        q = points_above_table(p, plane_from_world)
        if q is not None:
            local[i] = q
    out: dict[int, HiddenTop] = {}
    for a, pa in local.items():
        if carriers is not None and a not in carriers:
            continue
        for b, pb in local.items():
            if b == a:
                continue
            top = _hidden_top(pa, pb, eye, cell_m)
            if top is None:
                continue
            pts = transform_points(world_from_pl, top[1])
            if a not in out or len(pts) > len(out[a].points_world):
                out[a] = HiddenTop(a, b, top[0], pts)
    return out


def points_above_table(points_world: np.ndarray, plane_from_world: np.ndarray
                       ) -> np.ndarray | None:
    """(N, 3) ``points_world`` in the support plane's frame (``plane_from_world`` (4, 4)),
    without those in the table band and the isolated ones (flying pixels would stretch a
    footprint); None when fewer than ``MIN_POINTS`` are left."""
    q = transform_points(plane_from_world,
                         np.asarray(points_world, dtype=np.float64).reshape(-1, 3))
    q = q[q[:, 2] > TABLE_BAND_M]
    if len(q) > 20:
        q = q[drop_isolated(q)]
    return q if len(q) >= MIN_POINTS else None


def view_axes(points_plane: np.ndarray, eye_plane: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray] | None:
    """(along, across) unit (2,) directions in the table's plane: from the camera centre
    ``eye_plane`` (3,) towards the mean of ``points_plane`` (N, 3), and across it; None
    when the camera is straight above them (every top is seen)."""
    along_dir = points_plane[:, :2].mean(axis=0) - eye_plane[:2]
    norm = float(np.linalg.norm(along_dir))
    if norm < 1e-6:
        return None
    along_dir = along_dir / norm
    return along_dir, np.array([-along_dir[1], along_dir[0]])


def _hidden_top(pa: np.ndarray, pb: np.ndarray, eye: np.ndarray, cell_m: float
                ) -> tuple[float, np.ndarray] | None:
    """(height m, (M, 3) plane-frame points) of carrier ``pa``'s hidden top under
    ``pb`` (both (N, 3) plane frame, table band removed), or None when ``pb`` does not
    rest on a carrier that shows no top (the tests of the module docstring)."""
    z_top = float(np.percentile(pa[:, 2], TOP_PERCENTILE))
    edge = pa[pa[:, 2] >= z_top - EDGE_BAND_M]
    dist, _ = cKDTree(edge).query(pb, distance_upper_bound=CONTACT_M)
    if np.count_nonzero(np.isfinite(dist)) < MIN_CONTACT_POINTS:
        return None
    b_low = float(np.percentile(pb[:, 2], 5))
    if b_low < z_top - ABOVE_TOLERANCE_M:
        return None
    axes = view_axes(pa, eye)
    if axes is None:
        return None
    along_dir, across_dir = axes
    along_a, across_a = pa[:, :2] @ along_dir, pa[:, :2] @ across_dir
    face_far = float(np.percentile(along_a, 95))
    if face_far - float(np.percentile(along_a, 5)) > MAX_THICKNESS_RATIO * z_top:
        return None
    if float(np.percentile(pb[:, :2] @ along_dir, 90)) - face_far < MIN_BEYOND_M:
        return None
    grid = _footprint_grid(pb[:, :2], cell_m)
    if grid is None:
        return None
    along_g, across_g = grid @ along_dir, grid @ across_dir
    keep = ((along_g >= float(np.median(along_a)))
            & (along_g <= float(np.percentile(pb[:, :2] @ along_dir, FAR_PERCENTILE)))
            & (across_g >= float(np.percentile(across_a, 2)) - cell_m)
            & (across_g <= float(np.percentile(across_a, 98)) + cell_m))
    if np.count_nonzero(keep) < MIN_CONTACT_POINTS:
        return None
    height = min(z_top, b_low)
    return height, np.c_[grid[keep], np.full(np.count_nonzero(keep), height)]


def _footprint_grid(xy: np.ndarray, cell_m: float) -> np.ndarray | None:
    """(M, 2) grid points (spacing ``cell_m``) inside the convex hull of ``xy`` (N, 2)."""
    try:
        hull = Delaunay(xy)
    except QhullError:
        return None
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0] + cell_m / 2, cell_m),
                         np.arange(lo[1], hi[1] + cell_m / 2, cell_m), indexing="ij")
    grid = np.c_[gx.ravel(), gy.ravel()]
    return grid[hull.find_simplex(grid) >= 0]
