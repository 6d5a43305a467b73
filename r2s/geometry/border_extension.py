"""Objects cut by the image border: where their hidden part goes, and how far.

Conventions: OpenCV camera frame, pixels ``(row, col)``; the support plane's frame
(:func:`r2s.geometry.plane.world_from_plane`: z up, the table at z = 0); world frame as
``world_from_camera`` declares it. Distances in metres.

A completion without a prior ends where the observed points end. For an object the image
border cuts, that is the frustum's side plane, not the object's end: a ball cut in half
by the left edge of the picture would be completed as half a ball. The camera saw nothing
beyond the border, so the extent there is a guess, and the guess made here is a short,
continuous one. In the support plane, across the cut, the object is seen ``d`` deep (from
the cut inwards) and ``w`` wide along it. The hidden part is the visible part's band
``e = min(d, w, max_extent_m)`` deep next to the cut, reflected about the cut (a
roundish footprint) or carried on along the footprint's long axis (an elongated one
crossing the cut at a slant, which a mirror image would bend into a V): a ball cut through
its middle is completed whole; a long thing crossing the border continues along its own
axis by its own width, with its own profile; a sliver at the border continues by as
little as it is seen deep. Along a left or right border the cut runs roughly along the
view, where an object hides its own far side, so ``w`` is only what is seen of it: the
guess stays short rather than long.

The frustum's side planes lean (the bottom one steeply, for a camera looking down), so the
cut is not one line on the table: at each height it is where the plane passes. A point is
reflected about the cut at the table or at its own height, whichever lies farther out
(:meth:`BorderCut.beyond_m`): the completion extrudes every column down to the table, and
a column reflected about the cut at the point's height alone could come back into the
picture lower down, under or behind an object the camera saw there.

:func:`border_cap_points` returns those points; the completion adds them to the
observed ones, so they widen the footprint and set the heights there, and its carving
against the depth image still removes whatever part of them the camera saw past.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay, QhullError

from r2s.geometry.camera import transform_points
from r2s.geometry.plane import world_from_plane

MAX_EXTENT_M = 0.15
"""The hidden part reaches at most this far beyond the border."""
MIN_BORDER_POINTS = 8
"""A side of the image cuts the object when at least this many of its observed points lie
within ``edge_px`` of it."""
MIN_ACROSS = 0.87
"""Only a side whose frustum plane stands within 30 degrees of vertical (the horizontal
part of its normal at least this) is extended across. Where the plane leans more (the
bottom of the picture, for a camera looking down at a table) what it hides of an object is
mostly below what is seen, and the completion's columns already reach down to the table;
a reflection across such a plane throws a vertical face out in front of itself (measured:
a wood block 119 x 120 mm cut by the bottom of a cropped scene grew to 182 x 251 mm)."""


@dataclass(frozen=True)
class BorderCut:
    """One image side cutting an object, in the support plane's frame.

    The side's frustum plane meets the horizontal plane at height ``z`` along a line at
    ``trace_m + slope * z`` along ``outward`` (the plane leans, so the line moves with the
    height). A column of the completion, which reaches down to the table, lies wholly
    beyond the border at ``x`` along ``outward`` when ``x`` passes the line at every height
    from the table up: :meth:`beyond_m` is that bound for a point at height ``z``.

    side : "left", "right", "top" or "bottom".
    outward : (2,) unit, across the cut, out of the image.
    trace_m : the line's position at the table (z = 0); slope : its change per metre up.
    visible_m : ``d``, how deep the object is seen inwards of the bound.
    width_m : ``w``, how wide it is seen along the cut (5th to 95th percentile of its points
        within ``edge_px`` of the border).
    extent_m : ``e``, how far the hidden part reaches beyond the cut.
    """

    side: str
    outward: np.ndarray
    trace_m: float
    slope: float
    visible_m: float
    width_m: float
    extent_m: float

    def beyond_m(self, z: np.ndarray) -> np.ndarray:
        """(N,) the bound along ``outward`` past which a column up to height ``z`` (N,) is
        outside the image at every height (:func:`_column_bound_m`)."""
        return _column_bound_m(self.trace_m, self.slope, z)


def _column_bound_m(trace_m: float, slope: float, z: np.ndarray) -> np.ndarray:
    """(N,) where a lean side plane's line lies at height ``z`` (N,) or at the table,
    whichever is farther out: ``trace_m + max(0, slope * z)``."""
    z = np.clip(np.asarray(z, dtype=np.float64), 0.0, None)
    return trace_m + np.maximum(0.0, slope * z)


def _outward_normal_camera(side: str, K: np.ndarray, width: int, height: int) -> np.ndarray:
    """(3,) unit normal of the frustum's side plane, camera frame, pointing out of the image."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if side in ("left", "right"):
        u0 = -0.5 if side == "left" else width - 0.5
        n = np.array([1.0, 0.0, -(u0 - cx) / fx])  # x - a z = 0, towards larger u
        n = -n if side == "left" else n
    else:
        v0 = -0.5 if side == "top" else height - 0.5
        n = np.array([0.0, 1.0, -(v0 - cy) / fy])
        n = -n if side == "top" else n
    return n / np.linalg.norm(n)


def _border_rows(pixels: np.ndarray, side: str, width: int, height: int, edge_px: int
                 ) -> np.ndarray:
    rows, cols = pixels[:, 0], pixels[:, 1]
    return {"left": cols < edge_px, "right": cols >= width - edge_px,
            "top": rows < edge_px, "bottom": rows >= height - edge_px}[side]


def border_cuts(points_plane: np.ndarray, pixels: np.ndarray, K: np.ndarray,
                world_from_camera: np.ndarray, plane_from_world: np.ndarray, width: int,
                height: int, edge_px: int = 2, max_extent_m: float = MAX_EXTENT_M
                ) -> list[BorderCut]:
    """The image sides that cut the object whose observed points are ``points_plane``
    ((N, 3), support plane frame) seen at ``pixels`` ((N, 2) row, col)."""
    K = np.asarray(K, dtype=np.float64)
    world_from_camera = np.asarray(world_from_camera, dtype=np.float64)
    plane_from_world = np.asarray(plane_from_world, dtype=np.float64)
    rot = plane_from_world[:3, :3] @ world_from_camera[:3, :3]
    eye = plane_from_world[:3, :3] @ world_from_camera[:3, 3] + plane_from_world[:3, 3]
    cuts = []
    for side in ("left", "right", "top", "bottom"):
        on_border = _border_rows(pixels, side, width, height, edge_px)
        if on_border.sum() < MIN_BORDER_POINTS:
            continue
        normal = rot @ _outward_normal_camera(side, K, width, height)
        across = float(np.linalg.norm(normal[:2]))
        if across < MIN_ACROSS:
            continue
        outward = normal[:2] / across
        # the plane n . (p - eye) = 0 at height z: (outward . p_xy) = trace + slope z
        trace = float(outward @ eye[:2] + normal[2] * eye[2] / across)
        slope = float(-normal[2] / across)
        inside = _column_bound_m(trace, slope, points_plane[:, 2]) - points_plane[:, :2] @ outward
        visible = float(np.percentile(inside, 98))
        along = np.array([-outward[1], outward[0]])
        lo, hi = np.percentile(points_plane[on_border, :2] @ along, [5, 95])
        extent = min(visible, float(hi - lo), max_extent_m)
        if extent > 1e-3:
            cuts.append(BorderCut(side, outward, trace, slope, visible, float(hi - lo),
                                  extent))
    return cuts


ELONGATED_RATIO = 2.0
"""A footprint whose principal spreads (standard deviations) differ by this factor is
elongated: it continues along its long axis..."""
MIN_AXIS_COSINE = 0.8
"""...when that axis crosses the cut within 37 degrees of its normal. A round thing cut
through its middle leaves a footprint elongated along the cut. Measured on a cropped
benchmark scene with a limit of 60 degrees: a ball 130 mm across was carried along such an
axis and grew sideways from 88 to 159 mm (its true width 127 mm)."""


def _continuation(xy: np.ndarray, outward: np.ndarray) -> np.ndarray:
    """(2,) the displacement per unit of depth ``t`` inside the cut that takes a point to
    ``t`` beyond it: ``outward`` (a mirror image about the cut) for a roundish footprint,
    along the long axis for an elongated one crossing the cut at a slant (a bar at 30
    degrees continues at 30 degrees; its mirror image would bend it into a V)."""
    centred = xy - xy.mean(axis=0)
    values, vectors = np.linalg.eigh(centred.T @ centred / max(len(xy), 1))
    long_axis = vectors[:, 1]
    cos = float(long_axis @ outward)
    if values[1] < ELONGATED_RATIO ** 2 * max(values[0], 1e-12) or abs(cos) < MIN_AXIS_COSINE:
        return np.asarray(outward, dtype=np.float64)
    return long_axis / cos  # its component along ``outward`` is 1


SWALLOW_MAX_POINTS = 10
"""The extension may not bring more than this many of a neighbour's observed points under
the object's footprint (its convex hull) than were under it before."""
SHRINK_TRIES = 3


def _newly_covered(own_xy: np.ndarray, cap_xy: np.ndarray, others_xy: np.ndarray) -> int:
    """How many of ``others_xy`` (M, 2) the convex hull of ``own_xy`` and ``cap_xy``
    covers and the hull of ``own_xy`` alone does not."""
    if len(others_xy) == 0 or len(cap_xy) == 0:
        return 0
    try:
        grown = Delaunay(np.concatenate([own_xy, cap_xy])).find_simplex(others_xy) >= 0
        if not grown.any():
            return 0
        before = Delaunay(own_xy).find_simplex(others_xy[grown]) >= 0
    except QhullError:
        return 0
    return int(np.count_nonzero(~before))


def border_cap_points(points_world: np.ndarray, pixels: np.ndarray, K: np.ndarray,
                      world_from_camera: np.ndarray, width: int, height: int,
                      plane_point: np.ndarray, plane_normal: np.ndarray, edge_px: int = 2,
                      max_extent_m: float = MAX_EXTENT_M,
                      others_world: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The observed points next to each cut, continued beyond it (module docstring).

    Parameters
    ----------
    points_world : (N, 3) the object's observed points, world frame; pixels : (N, 2) their
        (row, col). K : (3, 3); world_from_camera : (4, 4); width, height : the image.
    plane_point, plane_normal : (3,) the support plane (normal up).
    others_world : (K, 3) the other objects' observed points, world frame, or None. An
        extension that would bring more than :data:`SWALLOW_MAX_POINTS` of them under the
        object's footprint (the convex hull the completion takes) is halved, up to
        :data:`SHRINK_TRIES` times, and then left out: a neighbour the camera saw beside the
        cut is not swallowed by a guess about what lies beyond it.

    Returns
    -------
    (M, 3) world points (M = 0 when no side cuts the object) and (M,) the index of the
    observed point each one continues (for its colour).
    """
    pts_w = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    pixels = np.asarray(pixels).reshape(-1, 2)
    empty = np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    if len(pts_w) < MIN_BORDER_POINTS:
        return empty
    world_from_pl = world_from_plane(plane_point, plane_normal)
    plane_from_world = np.linalg.inv(world_from_pl)
    pts = transform_points(plane_from_world, pts_w)
    cuts = border_cuts(pts, pixels, K, world_from_camera, plane_from_world, width, height,
                       edge_px, max_extent_m)
    others_xy = (np.zeros((0, 2)) if others_world is None or len(others_world) == 0 else
                 transform_points(plane_from_world,
                                  np.asarray(others_world, dtype=np.float64).reshape(-1, 3))[:, :2])
    out, src = [], []
    for cut in cuts:
        bound = cut.beyond_m(pts[:, 2])
        inside = bound - pts[:, :2] @ cut.outward  # >= 0 for what the camera saw
        step = _continuation(pts[:, :2], cut.outward)
        extent = cut.extent_m
        for _ in range(SHRINK_TRIES + 1):
            band = np.flatnonzero((inside >= 0.0) & (inside <= extent))
            continued = pts[band].copy()
            continued[:, :2] += (2.0 * inside[band])[:, None] * step[None]
            if _newly_covered(pts[:, :2], continued[:, :2], others_xy) <= SWALLOW_MAX_POINTS:
                out.append(continued)
                src.append(band)
                break
            extent /= 2.0
    if not out:
        return empty
    return transform_points(world_from_pl, np.concatenate(out)), np.concatenate(src)
