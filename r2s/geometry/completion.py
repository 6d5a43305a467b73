"""Complete a closed mesh of an object seen from one view, with no shape prior.

The observed points are expressed in the support plane's frame (z up) and turned into a
height field: the top surface is the highest point in each grid cell, the footprint is
the convex hull of the points projected on the plane (the back of an object is not seen
from one view, but its top usually is), unseen cells take heights interpolated from
observed ones, and every column is extruded down to the surface the object stands on:
the support plane, or the top of what is under it. A bowl keeps its dip because each
column keeps its own top.

The solid is the zero level set of ``min(-footprint_sdf(x, y), top(x, y) - z,
z - bottom(x, y))``, meshed by marching cubes on a padded grid, which gives a closed,
watertight surface with vertical walls along the hull.

Given the depth view (:class:`~r2s.geometry.carving.CarveView`), the solid is carved
before meshing: every grid node the camera saw past (in front of a valid reading at a pixel
that is not the object's own) is free space and becomes outside, so the extrusion keeps
only what the camera could not see: behind the visible surface, behind nearer objects,
below, in depth holes and outside the image. Pieces left with less than
``MIN_PIECE_FRACTION`` of the largest piece's volume are dropped.

An object seen past the top of something nearer continues behind it: the footprint is
swept towards the camera (along the horizontal viewing direction only, never sideways)
by at most ``extend_fraction`` of its visible size (and ``extend_max_m``), keeping the
swept cells whose top (the nearest visible top height) is hidden by something other than
the object itself, connected to the visible footprint. Cells whose top the camera would
have seen stay empty, and nothing grows into the object's own shadow. Off by default: on
three oblique synthetic scenes (scripts/bench_completion.py) a sweep of 0.5 helped the
most occluded object and hurt objects next to nearer ones (a marker grown from 40 to
74 mm), since the hidden space does not say where the object ends.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import trimesh
from scipy import ndimage
from scipy.interpolate import griddata
from scipy.spatial import ConvexHull, Delaunay, QhullError, cKDTree
from skimage.measure import marching_cubes

from r2s.geometry.camera import transform_points
from r2s.geometry.carving import CarveView, hidden_by_other, seen_as_other, seen_free
from r2s.geometry.plane import world_from_plane
from r2s.geometry.sdf import raycasting_scene


@dataclass(frozen=True)
class CompletedShape:
    """A completed object.

    Attributes
    ----------
    mesh : closed triangle mesh in the object frame (metres), with vertex colours when
        colours were given. The object frame has the plane frame's axes; its origin is
        the footprint centre at the bottom of the mesh.
    world_from_object : (4, 4) rigid.
    bottom_m : height of the object's base above the support plane (0 on the table).
    carved_fraction : share of the extruded solid's grid nodes removed as seen free space
        (0 without a view).
    """

    mesh: trimesh.Trimesh
    world_from_object: np.ndarray
    bottom_m: float
    carved_fraction: float = 0.0
    bridged: bool = False
    """Whether it lies across others (:func:`_bridge` raised its free columns)."""


MIN_PIECE_FRACTION = 0.1
BRIDGE_MIN_SHARE = 0.1
"""An object lies across others when their tops carry at least this share of its
footprint's columns (:func:`_bridge`)."""
BRIDGE_THICKNESS_PERCENTILE = 50.0
"""Its thickness is this percentile of (its top - the top under it) over the carried
columns: where it touches what it lies on, not over a round support's falling rim."""
BRIDGE_MAX_THICKNESS_RATIO = 0.5
"""...and it is bridged only when that thickness is at most this share of its height
over the table in the free columns (a thin thing across others, not a tall one beside a
low one)."""
BRIDGE_MAX_POINTS_BELOW = 0.05
"""...and only when nearly all its observed points lie within the bridged solid."""


@dataclass(frozen=True)
class BridgeGuards:
    """When an object found lying across others is bridged (:func:`_bridge`).

    max_thickness_ratio : its thickness where it rests over its median height in the free
        columns, at most.
    com_margin_cells : how far (grid cells) its centre of mass may lie outside the hull of
        the carried columns.
    """

    max_thickness_ratio: float = BRIDGE_MAX_THICKNESS_RATIO
    com_margin_cells: float = 0.0


STRICT_BRIDGE = BridgeGuards()
"""The guards of the completion init keeps."""

RELAXED_BRIDGE = BridgeGuards(max_thickness_ratio=0.7, com_margin_cells=1.0)
"""Looser guards, for the second completion physopt may swap in where the first cannot
rest near where it was seen (r2s/stages/init.py, ``init/alternates/``). A clamp lying on
another clamp and a cup in the realistic benchmark's scene_05 is 0.61 of its height thick
where it rests, and its centre of mass lies 0.7 mm (a quarter of a cell) outside what
carries it; as the first completion these guards took a cup leaning on a banana (scene_02)
off the table, so they only make the alternative."""
NO_BRIDGE = BridgeGuards(max_thickness_ratio=0.0)
"""Guards that never bridge (every thickness is above zero): the completion whose free
columns reach down to the table, the alternative init keeps for a bridged object."""
EXTEND_FRACTION = 0.0
EXTEND_MAX_M = 0.05
HULL_TOLERANCE_M = 1e-9
"""A grid column on a facet of the carried columns' hull (rounding aside) is over it."""


def footprint_sdf(hull_equations: np.ndarray | Sequence[np.ndarray], xy: np.ndarray
                  ) -> np.ndarray:
    """Signed distance-like field of a convex polygon, or a union of them, negative inside.

    ``max_k (n_k . xy + c_k)`` over the hull's edge lines (unit outward normals); exact on
    the boundary and inside, a lower bound of the distance outside. For a union, the
    minimum over its polygons.

    hull_equations : (K, 3) ``[nx, ny, c]`` rows of ``scipy.spatial.ConvexHull.equations``,
        or a list of such arrays (a union of polygons).
    xy : (..., 2). Returns (...,).
    """
    if isinstance(hull_equations, (list, tuple)):
        return np.min([footprint_sdf(eq, xy) for eq in hull_equations], axis=0)
    eq = np.asarray(hull_equations, dtype=np.float64)
    return np.max(xy @ eq[:, :2].T + eq[:, 2], axis=-1)


MIN_PART_POINTS = 10
"""A part of the mask with fewer points has no footprint of its own: its points join the
hull of the nearest part."""


def part_hulls(xy_points: np.ndarray, parts: np.ndarray) -> list[np.ndarray] | None:
    """The hull equations (:func:`footprint_sdf`) of each part's points: ``xy_points``
    (N, 2, plane frame), ``parts`` (N,) int. None when fewer than two parts have
    :data:`MIN_PART_POINTS` points or a part's points lie on a line; a smaller part's
    points join the part whose points lie nearest to them.

    An object seen on both sides of an occluder (a drill's body and a sliver of it past a
    toy plane) then need not fill the space between with one hull across the occluder
    and whatever stands there (:func:`_footprint` chooses)."""
    labels, counts = np.unique(parts, return_counts=True)
    big = labels[counts >= MIN_PART_POINTS]
    if len(big) < 2:
        return None
    owner = np.asarray(parts).copy()
    small = ~np.isin(owner, big)
    if small.any():
        big_pts = np.isin(owner, big)
        _, nn = cKDTree(xy_points[big_pts]).query(xy_points[small])
        owner[small] = owner[big_pts][nn]
    try:
        return [ConvexHull(xy_points[owner == label]).equations for label in big]
    except QhullError:
        return None


INSIDE_MARGIN_M = 0.005
"""Another object's point this far or more below an object's top height is inside its
column (:func:`_footprint`)."""
INSIDE_MIN_POINTS = 3
"""...and a grid cell holding at least this many such points is the other object's."""


def _footprint(pts: np.ndarray, parts: np.ndarray | None, hull: ConvexHull, gx: np.ndarray,
               gy: np.ndarray, top: np.ndarray, others: np.ndarray | list[np.ndarray] | None,
               cell: float) -> np.ndarray | list[np.ndarray]:
    """The footprint (hull equations for :func:`footprint_sdf`) of an object's points
    ``pts`` (N, 3, plane frame) on the grid ``gx, gy``: the hull of them all, or the union
    of its parts' own hulls (:func:`part_hulls`) when another object is seen inside the
    columns the hull fills between the parts.

    The hull across the parts of a mask cut apart by an occluder is right for a plate seen
    past the fruit on it (the fruit is seen above the plate's top) and for a tool lying
    behind a toy. It is wrong where the occluder is seen below the top the object would
    have there (a strawberry on the table in front of a drill, between the drill's body and
    a sliver of it): the object goes around or behind it in a way one view does not show,
    so only the parts seen are kept. "Seen inside": a grid cell between the parts holds
    :data:`INSIDE_MIN_POINTS` of ``others``' points (plane frame, (M, 3) or a list of such)
    lower than ``top`` ((nx, ny) top heights) by :data:`INSIDE_MARGIN_M`."""
    if isinstance(others, list):
        others = np.concatenate(others) if others else None
    hulls = None if parts is None or others is None else part_hulls(pts[:, :2], parts)
    if hulls is None or len(others) == 0:
        return hull.equations
    xy = np.stack([gx, gy], axis=-1)
    # the grid's outer cells lie outside every hull (padding), so clipped points count nowhere
    between = (footprint_sdf(hull.equations, xy) <= 0) & (footprint_sdf(hulls, xy) > 0)
    ix, iy = _columns(others, gx[0, 0], gy[0, 0], *gx.shape, cell)
    low = others[:, 2] < top[ix, iy] - INSIDE_MARGIN_M
    count = np.zeros(gx.shape, dtype=int)
    np.add.at(count, (ix[low], iy[low]), 1)
    return hulls if np.any(between & (count >= INSIDE_MIN_POINTS)) else hull.equations


def _columns(pts: np.ndarray, x0: float, y0: float, nx: int, ny: int, cell_m: float
             ) -> tuple[np.ndarray, np.ndarray]:
    """(ix, iy) the grid column (nearest node, clipped to the grid) of each (N, 3) point."""
    ix = np.clip(np.floor((pts[:, 0] - x0) / cell_m + 0.5).astype(np.int64), 0, nx - 1)
    iy = np.clip(np.floor((pts[:, 1] - y0) / cell_m + 0.5).astype(np.int64), 0, ny - 1)
    return ix, iy


def _top_height_map(pts: np.ndarray, x0: float, y0: float, nx: int, ny: int,
                    cell_m: float) -> np.ndarray:
    """(nx, ny) highest point per cell, NaN where no point falls."""
    ix, iy = _columns(pts, x0, y0, nx, ny, cell_m)
    top = np.full((nx, ny), -np.inf)
    np.maximum.at(top, (ix, iy), pts[:, 2])
    top[~np.isfinite(top)] = np.nan
    return top


def _fill(values: np.ndarray, known: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """Fill unknown grid nodes: linear interpolation inside the known nodes' hull, nearest
    known node outside it."""
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    src = np.stack([gx[known], gy[known]], axis=1)
    out = values.copy()
    unknown = ~known
    if unknown.any():
        dst = np.stack([gx[unknown], gy[unknown]], axis=1)
        lin = np.full(len(dst), np.nan)
        if len(src) >= 4:
            try:
                lin = griddata(src, values[known], dst, method="linear")
            except QhullError:  # the known nodes on one line of the grid: nearest only
                pass
        miss = ~np.isfinite(lin)
        if miss.any():
            _, nn = cKDTree(src).query(dst[miss])
            lin[miss] = values[known][nn]
        out[unknown] = lin
    return out


def _beside(group: np.ndarray, hull_eq: np.ndarray | list[np.ndarray], z_low: float,
            margin_m: float, beside_share: float, beside_m: float, min_points: int) -> bool:
    """True when one other object's points (plane frame) within ``margin_m`` of the
    footprint rise past the object's lowest observed point ``z_low`` (by ``beside_m``, more
    than ``beside_share`` of them, at any height): a neighbour standing beside or in front
    of the object (an occluder hiding its lower part), not a support under it."""
    near = group[(footprint_sdf(hull_eq, group[:, :2]) < margin_m) & (group[:, 2] > margin_m / 2)]
    return len(near) >= min_points and bool(np.mean(near[:, 2] > z_low + beside_m) > beside_share)


def _support_height(pts: np.ndarray, below: np.ndarray | list[np.ndarray] | None,
                    hull_eq: np.ndarray | list[np.ndarray], margin_m: float,
                    min_points: int = 30,
                    envelope_percentile: float = 95.0, beside_share: float = 0.2,
                    beside_m: float = 0.003, lift_m: float = 0.005
                    ) -> tuple[float, np.ndarray | None]:
    """Height of what the object stands on, as a plane ``z = a x + b y + c`` or 0.

    Candidates are other objects' points under the footprint (grown by ``margin_m``) and
    below the object's lowest observed point (+ margin); none when more than
    ``beside_share`` of them rise above that point by ``beside_m`` (a neighbour beside the
    object, whose side passes the level where the object's visible part ends, not a
    support under it: a support's top is below everything seen of what rests on it), and
    none when they would lift the object by more than ``lift_m`` at the centre of its
    observed points while that centre is not over their convex hull (:func:`centre_over`). The
    plane fitted to them is raised
    to their ``envelope_percentile`` (what rests on a curved surface rests on its top),
    capped at the object's own lowest observed point. ``below`` given as a list (one array
    per other object) is judged per object first: an object whose points near the
    footprint rise past this one's lowest observed point at any height (:func:`_beside`)
    is left out, whatever part of it lies lower. Returns (min height over the candidates,
    coefficients (3,) or None for the support plane itself).
    """
    z_low = float(np.percentile(pts[:, 2], 1))
    if isinstance(below, list):
        kept = [g for g in below if len(g) and not _beside(g, hull_eq, z_low, margin_m,
                                                           beside_share, beside_m, min_points)]
        below = np.concatenate(kept) if kept else None
    if below is None or len(below) < min_points:
        return 0.0, None
    sel = below[(footprint_sdf(hull_eq, below[:, :2]) < margin_m)
                & (below[:, 2] < z_low + margin_m) & (below[:, 2] > margin_m / 2)]
    if len(sel) < min_points or np.mean(sel[:, 2] > z_low + beside_m) > beside_share:
        return 0.0, None
    a = np.c_[sel[:, 0], sel[:, 1], np.ones(len(sel))]
    coef, *_ = np.linalg.lstsq(a, sel[:, 2], rcond=None)
    if np.hypot(coef[0], coef[1]) > np.tan(np.radians(30)):
        coef = np.array([0.0, 0.0, float(np.median(sel[:, 2]))])
    # an object rests on the highest points of what is under it (the crown of a lying can,
    # not the mean of its sides): raise the plane to the upper envelope of the candidates,
    # but never above the object's own lowest observed points
    coef = coef.copy()
    coef[2] += float(np.percentile(sel[:, 2] - a @ coef, envelope_percentile))
    coef[2] = min(coef[2], z_low - float(np.mean(coef[:2] @ pts[:, :2].T)))
    centre = pts[:, :2].mean(axis=0)
    if coef[:2] @ centre + coef[2] > lift_m and not centre_over(sel[:, :2], centre):
        return 0.0, None  # what is under its edge only cannot carry it
    return float(sel[:, 2].min()), coef


def centre_over(support_xy: np.ndarray, centre_xy: np.ndarray) -> bool:
    """Whether ``centre_xy`` (2,) lies over the convex hull of ``support_xy`` (N, 2): an
    object rests on another only where that one is under its centre, not along one edge
    of it (a cup seen past a marker lying in front of it stands on the table behind the
    marker; realistic benchmark scene_04). False for fewer than 3 points or points on a
    line (no area to rest on)."""
    if len(support_xy) < 3:
        return False
    try:
        return bool(Delaunay(support_xy).find_simplex(centre_xy) >= 0)
    except QhullError:
        return False


def _tops_below(meshes_world: Sequence[trimesh.Trimesh], plane_from_world: np.ndarray,
                gx: np.ndarray, gy: np.ndarray, ceiling: np.ndarray) -> np.ndarray:
    """(nx, ny) per grid column (plane frame, centres ``gx``, ``gy``) the highest top
    surface of the given meshes that lies below ``ceiling`` (nx, ny), 0 where none does.
    A mesh whose top in a column reaches the ceiling stands beside or in front of the
    object there, not under it, and does not count in that column."""
    import open3d as o3d  # heavy import, only where needed

    out = np.zeros(gx.shape)
    start = max(float(np.nanmax(ceiling)), 0.0) + 1.0
    rays = np.zeros(gx.shape + (6,), dtype=np.float32)
    rays[..., 0], rays[..., 1], rays[..., 2], rays[..., 5] = gx, gy, start, -1.0
    for mesh in meshes_world:
        local = transform_points(plane_from_world, np.asarray(mesh.vertices))
        scene = raycasting_scene(local, np.asarray(mesh.faces))
        t_hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        top = start - t_hit.astype(np.float64)
        below = np.isfinite(top) & (top < ceiling) & (top > 0.0)
        out = np.where(below, np.maximum(out, top), out)
    return out


def _bridge(bottom: np.ndarray, under: np.ndarray, top: np.ndarray, inside: np.ndarray,
            gx: np.ndarray, gy: np.ndarray, cell: float, pts: np.ndarray,
            guards: BridgeGuards = STRICT_BRIDGE) -> np.ndarray:
    """(nx, ny) ``bottom`` raised, for an object lying across others, to its thickness
    below its top in the columns where nothing carries it.

    ``under``: per column the top of the other object under this one (0: none; the
    columns with one are the carried ones); ``inside``: the
    footprint's columns; ``gx``, ``gy``: column centres (plane frame); ``pts``: (N, 3)
    the object's observed points (plane frame). When at least
    ``BRIDGE_MIN_SHARE`` of the footprint is carried, the object's thickness is taken
    where it rests (``BRIDGE_THICKNESS_PERCENTILE`` of top - bottom over the carried
    columns, at least two cells). The free columns end that far below the top instead of
    reaching down to the table (a clamp across a can and a box spans the gap between
    them: it is rigid, and the space under it, which the camera could not see, stays
    empty). Where it overhangs what carries it, they also end no lower than the nearest
    top that carries it (:func:`_carrier_floor`: a clamp on a block whose handle
    overhangs the block's edge does not hang below the block's top, where it would rest
    on the edge and tip; a support plane fitted to points under the object, often a
    neighbour's side, does not shape them), when

    - that thickness is at most ``guards.max_thickness_ratio`` of the object's median
      height in the free columns (a thin thing across others, not a tall one beside a
      low one), and
    - the bridged solid's centre of mass (column volumes, uniform density) lies over the
      convex hull of the carried columns, or within ``guards.com_margin_cells`` of it:
      what carries it can hold it. A board with one
      end on a box and its top level over the table beyond keeps reaching the table;
    - at most ``BRIDGE_MAX_POINTS_BELOW`` of the object's own observed points lie more
      than a cell below the bridged underside of their column: a fruit whose side is seen
      down to 17 mm beside a drill whose first completion reaches under it stands on the
      table, not on the drill.
    """
    carried = under > 0
    on = carried & inside
    free = inside & ~carried
    if not free.any() or on.sum() < max(BRIDGE_MIN_SHARE * inside.sum(), 3):
        return bottom
    thickness = max(float(np.percentile(top[on] - bottom[on], BRIDGE_THICKNESS_PERCENTILE)),
                    2 * cell)
    if thickness > guards.max_thickness_ratio * float(np.median(top[free])):
        return bottom
    try:
        hull = ConvexHull(np.c_[gx[on], gy[on]])
    except QhullError:
        return bottom  # the carried columns are on a line: no area to stand on
    ix, iy = _columns(pts, gx[0, 0], gy[0, 0], *gx.shape, cell)
    floor = _carrier_floor(under, on, hull.equations, pts, ix, iy, gx, gy, cell)
    bridged = np.where(free, np.maximum(top - thickness, floor), bottom)
    weight = np.where(inside, np.clip(top - bridged, 0.0, None), 0.0)
    com = np.array([np.sum(weight * gx), np.sum(weight * gy)]) / max(float(weight.sum()), 1e-12)
    if np.max(hull.equations[:, :2] @ com + hull.equations[:, 2]) > guards.com_margin_cells * cell:
        return bottom
    if np.mean(pts[:, 2] < bridged[ix, iy] - cell) > BRIDGE_MAX_POINTS_BELOW:
        return bottom
    return bridged


def _carrier_floor(under: np.ndarray, on: np.ndarray, hull_equations: np.ndarray,
                   pts: np.ndarray, px: np.ndarray, py: np.ndarray, gx: np.ndarray,
                   gy: np.ndarray, cell: float) -> np.ndarray:
    """(nx, ny) the lowest a bridged object's underside may hang in each column where it
    overhangs what carries it (outside ``hull_equations``, (F, 3) the convex hull of the
    carried columns ``on``, plane frame): the top under it in the nearest carried column
    (``under`` the tops), but a cell below the lowest of its own observed points (``pts``,
    plane frame, in columns ``px``, ``py``) in the column where it has some (what is seen
    lower than its carrier's top is seen hanging there). Columns over the hull, a gap it
    spans between carriers, get no floor (-inf)."""
    _, (ix, iy) = ndimage.distance_transform_edt(~on, return_indices=True)
    floor = under[ix, iy]
    lowest = np.full(gx.shape, np.inf)
    np.minimum.at(lowest, (px, py), pts[:, 2])
    floor = np.minimum(floor, lowest - cell)
    over = (hull_equations[:, 0] * gx[..., None] + hull_equations[:, 1] * gy[..., None]
            + hull_equations[:, 2])
    span = np.all(over <= HULL_TOLERANCE_M, axis=-1)
    return np.where(span, -np.inf, floor)


def drop_isolated(points: np.ndarray, k: int = 8, factor: float = 4.0) -> np.ndarray:
    """(N,) bool: points whose k-th neighbour is no farther than ``factor`` times the
    median k-th-neighbour distance (mixed "flying" pixels at depth edges are isolated)."""
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) <= k:
        return np.ones(len(pts), dtype=bool)
    dist, _ = cKDTree(pts).query(pts, k=k + 1)
    kth = dist[:, -1]
    return kth <= factor * max(float(np.median(kth)), 1e-9)


def complete_from_points(points_world: np.ndarray, plane_point: np.ndarray,
                         plane_normal: np.ndarray, colors: np.ndarray | None = None,
                         cell_m: float = 0.003,
                         below_points_world: np.ndarray | list[np.ndarray] | None = None,
                         max_cells: int = 160, median_px: int = 3,
                         hull_margin_m: float = 0.0, outlier_factor: float = 4.0,
                         view: CarveView | None = None,
                         extend_fraction: float = EXTEND_FRACTION,
                         extend_max_m: float = EXTEND_MAX_M,
                         exclude: Callable[[np.ndarray], np.ndarray] | None = None,
                         under_meshes_world: Sequence[trimesh.Trimesh] = (),
                         point_parts: np.ndarray | None = None,
                         bridge_guards: BridgeGuards = STRICT_BRIDGE) -> CompletedShape:
    """Complete a watertight mesh from one partial view of an object on a plane.

    Parameters
    ----------
    points_world : (N, 3) the object's observed points, world frame (N >= 10).
    plane_point, plane_normal : (3,) the support plane (normal up).
    colors : (N, 3) uint8 colour of each point, or None.
    cell_m : grid cell size (grown so no side has more than ``max_cells`` cells).
    below_points_world : (M, 3) other objects' observed points, or a list of them, one
        (M_k, 3) array per object; those under the footprint and below this object raise
        its base (an object standing on another one). Per object, one that rises past
        this object's lowest observed point near its footprint is beside it, not under it.
    median_px : size of the median filter that clips spikes of the top heights (1 = none).
    hull_margin_m : grow the footprint by this much; a fraction of the pixel footprint on
        the surface makes up for the outermost samples lying inside the true outline.
    outlier_factor : points far from their neighbours (see :func:`drop_isolated`) are
        ignored, so that mixed pixels behind an edge do not stretch the footprint;
        0 keeps every point.
    view : the depth view to carve against (see the module docstring), or None.
    extend_fraction, extend_max_m : how far the footprint may be swept towards the camera
        into space hidden by something nearer (with a view; 0 = not at all).
    exclude : world points (M, 3) -> (M,) bool, space another object owns
        (:func:`r2s.geometry.hidden_partition.exclusion`), removed like seen free space.
    under_meshes_world : other objects' closed meshes (world frame). In every column where
        one's top surface lies below this object's top (by more than two cells), this
        object's base is raised onto it: what lies across other objects rests on them
        instead of reaching down to the table between and through them.
    point_parts : (N,) int, the part of the mask each point was seen in (the mask cut in
        parts by an occluder, :func:`r2s.geometry.point_cleanup.part_labels`), or None.
        With two parts or more the footprint may be the union of the parts' own hulls
        instead of one hull across the occluder between them (:func:`_footprint`).
    bridge_guards : when an object over ``under_meshes_world`` is bridged (:func:`_bridge`).

    Returns
    -------
    :class:`CompletedShape`; ``ValueError`` for degenerate input (collinear points).
    """
    pts_w = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    bridged = False
    keep = np.all(np.isfinite(pts_w), axis=1)
    if outlier_factor > 0 and keep.sum() > 20:
        keep[keep] = drop_isolated(pts_w[keep], factor=outlier_factor)
    pts_w = pts_w[keep]
    parts = None if point_parts is None else np.asarray(point_parts).reshape(-1)[keep]
    if len(pts_w) < 10:
        raise ValueError("completion needs at least 10 observed points")
    world_from_pl = world_from_plane(plane_point, plane_normal)
    plane_from_world = np.linalg.inv(world_from_pl)
    pts = transform_points(plane_from_world, pts_w)
    pts[:, 2] = np.maximum(pts[:, 2], 0.0)  # nothing is below the support
    try:
        hull = ConvexHull(pts[:, :2])
    except QhullError as exc:
        raise ValueError(f"observed points have no 2-D footprint ({exc.args[0][:40]})") from None
    lo = pts[:, :2].min(axis=0) - hull_margin_m
    hi = pts[:, :2].max(axis=0) + hull_margin_m
    cell = max(cell_m, float(np.max(hi - lo)) / max_cells, float(pts[:, 2].max()) / max_cells)
    reach = 0.0
    if view is not None and extend_fraction > 0 and extend_max_m > 0:
        reach = min(extend_fraction * float(np.max(hi - lo)), extend_max_m)
        lo, hi = lo - reach, hi + reach

    pad = 2
    nx, ny = (np.ceil((hi - lo) / cell).astype(int) + 1 + 2 * pad)
    x0, y0 = lo[0] - pad * cell, lo[1] - pad * cell
    xs = x0 + cell * np.arange(nx)
    ys = y0 + cell * np.arange(ny)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    below = None
    if isinstance(below_points_world, (list, tuple)):
        below = [transform_points(plane_from_world, np.asarray(g, dtype=np.float64).reshape(-1, 3))
                 for g in below_points_world]
    elif below_points_world is not None and len(below_points_world):
        below = transform_points(plane_from_world, below_points_world)

    top = _top_height_map(pts, x0, y0, nx, ny, cell)
    known = np.isfinite(top)
    if median_px > 1 and known.sum() > 9:
        # clip isolated spikes (flying pixels) to the local median of observed cells
        with warnings.catch_warnings():  # cells with no observed neighbour: NaN, fine
            warnings.simplefilter("ignore", RuntimeWarning)
            med = ndimage.generic_filter(top, np.nanmedian, size=median_px,
                                         mode="constant", cval=np.nan)
        top = np.where(known, np.minimum(top, med + 2 * cell), top)
    top = _fill(top, known, xs, ys)
    footprint = _footprint(pts, parts, hull, gx, gy, top, below, cell)
    sdf = footprint_sdf(footprint, np.stack([gx, gy], axis=-1)) - hull_margin_m

    _, coef = _support_height(pts, below, footprint, margin_m=0.01)
    if coef is None:
        bottom = np.zeros_like(top)
    else:
        bottom = np.clip(coef[0] * gx + coef[1] * gy + coef[2], 0.0, None)
    if len(under_meshes_world):
        under = _tops_below(under_meshes_world, plane_from_world, gx, gy, top - 2 * cell)
        bottom = np.maximum(bottom, under)
        raised = _bridge(bottom, under, top, sdf <= 0, gx, gy, cell, pts, bridge_guards)
        bridged = raised is not bottom  # _bridge returns ``bottom`` itself when it refuses
        bottom = raised
    # keep at least two cells of material in every column
    top = np.maximum(top, bottom + 2 * cell)
    inside_xy = -sdf
    if reach > 0:
        eye = transform_points(plane_from_world, view.world_from_camera[:3, 3][None])[0]
        grown = _hidden_extension(sdf, top, gx, gy, reach, cell, eye, pts, view,
                                  world_from_pl, hull.equations, hull_margin_m)
        inside_xy = np.where(grown, cell, inside_xy)

    z0 = float(bottom.min()) - pad * cell
    nz = int(np.ceil((top.max() - z0) / cell)) + pad + 1
    zs = z0 + cell * np.arange(nz)
    field = np.minimum.reduce([
        np.broadcast_to(inside_xy[:, :, None], (nx, ny, len(zs))),
        top[:, :, None] - zs[None, None, :],
        zs[None, None, :] - bottom[:, :, None],
    ])
    field = np.clip(field, -cell, cell)
    carved_fraction = 0.0
    if view is not None:
        field, carved_fraction = _carve(field, lambda p: seen_free(view, p), world_from_pl,
                                        xs, ys, zs, cell)
        field = _drop_columns_seen_as_other(field, view, world_from_pl, xs, ys, zs, cell)
    if exclude is not None:
        field, _ = _carve(field, exclude, world_from_pl, xs, ys, zs, cell)
    mesh, centre = mesh_field(field, np.array([x0, y0, z0]), cell)
    if colors is not None:
        cols = np.asarray(colors)[keep]
        _, nn = cKDTree(pts - centre).query(mesh.vertices)
        rgba = np.concatenate([cols[nn, :3], np.full((len(nn), 1), 255)], axis=1)
        mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=rgba.astype(np.uint8))
    plane_from_object = np.eye(4)
    plane_from_object[:3, 3] = centre
    return CompletedShape(mesh=mesh, world_from_object=world_from_pl @ plane_from_object,
                          bottom_m=float(centre[2]), carved_fraction=carved_fraction,
                          bridged=bridged)


def mesh_field(field: np.ndarray, origin: np.ndarray, cell: float
               ) -> tuple[trimesh.Trimesh, np.ndarray]:
    """The closed surface of a solid sampled on a grid, in its object frame.

    field : (nx, ny, nz) positive inside, on the grid ``origin + cell * index`` (plane
    frame, metres); origin : (3,) the first node.

    Returns the mesh (object frame: the plane's axes, origin at the centre of its
    footprint's bounding box on its base) and that origin in the plane frame (3,).
    """
    padded = np.pad(field, 1, mode="constant", constant_values=-cell)
    # a node exactly on the level set makes degenerate triangles: nudge it outside
    padded[np.abs(padded) < 1e-6 * cell] = -1e-6 * cell
    verts, faces, _, _ = marching_cubes(padded, level=0.0, spacing=(cell, cell, cell),
                                        gradient_direction="ascent")
    verts += np.asarray(origin, dtype=np.float64) - cell
    mesh = trimesh.Trimesh(verts, faces, process=False)
    if mesh.volume < 0:
        mesh.invert()
    lo_m, hi_m = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    centre = np.array([*(0.5 * (lo_m[:2] + hi_m[:2])), float(lo_m[2])])
    mesh.apply_translation(-centre)
    return mesh, centre


def _hidden_extension(sdf: np.ndarray, top: np.ndarray, gx: np.ndarray, gy: np.ndarray,
                      reach: float, cell: float, eye_plane: np.ndarray, pts: np.ndarray,
                      view: CarveView, world_from_pl: np.ndarray, hull_eq: np.ndarray,
                      hull_margin_m: float) -> np.ndarray:
    """(nx, ny) bool: cells outside the visible footprint (``sdf`` > 0), on its sweep of
    length ``reach`` towards the camera (``eye_plane``, plane frame), whose top is hidden
    by something else, connected to the footprint."""
    toward = eye_plane[:2] - pts[:, :2].mean(axis=0)
    if np.linalg.norm(toward) < 1e-9:
        return np.zeros(sdf.shape, dtype=bool)  # camera straight above: nothing hidden
    toward /= np.linalg.norm(toward)
    xy = np.stack([gx, gy], axis=-1)
    swept = np.zeros(sdf.shape, dtype=bool)
    for s in np.arange(cell / 2, reach + cell / 2, cell / 2):
        swept |= footprint_sdf(hull_eq, xy - s * toward) - hull_margin_m <= 0
    footprint = sdf <= 0
    candidate = swept & ~footprint
    if not candidate.any():
        return candidate
    tops = np.stack([gx[candidate], gy[candidate], top[candidate]], axis=1)
    hidden = np.zeros_like(candidate)
    hidden[candidate] = hidden_by_other(view, transform_points(world_from_pl, tops))
    # the first cells past the visible edge project onto the edge itself (the object's
    # own pixels): they bridge the footprint and the hidden cells beyond, but only there
    near = candidate & ndimage.binary_dilation(footprint, iterations=2)
    labels, _ = ndimage.label(footprint | hidden | near)
    attached = np.unique(labels[footprint])
    hidden &= np.isin(labels, attached[attached > 0])
    return hidden | (near & ndimage.binary_dilation(hidden, iterations=2))


def _carve(field: np.ndarray, is_free: Callable[[np.ndarray], np.ndarray],
           world_from_pl: np.ndarray, xs: np.ndarray, ys: np.ndarray, zs: np.ndarray,
           cell: float) -> tuple[np.ndarray, float]:
    """``field`` (nx, ny, nz), positive inside, with the nodes ``is_free`` says (world
    points (M, 3) -> (M,) bool: the camera saw past them, or another object owns them) set
    outside and small leftover pieces dropped; and the share of inside nodes removed.
    When carving would leave nothing, the field is returned unchanged (share 1.0)."""
    inside = np.argwhere(field > 0)
    if len(inside) == 0:
        return field, 0.0
    nodes = np.c_[xs[inside[:, 0]], ys[inside[:, 1]], zs[inside[:, 2]]]
    free = is_free(transform_points(world_from_pl, nodes))
    if not free.any():
        return field, 0.0
    out = field.copy()
    gone = inside[free]
    out[gone[:, 0], gone[:, 1], gone[:, 2]] = -cell
    if not _drop_small_pieces(out, cell):
        return field, 1.0
    return out, 1.0 - float(np.count_nonzero(out > 0)) / len(inside)


def _drop_small_pieces(field: np.ndarray, cell: float) -> bool:
    """Set outside, in place, the pieces of ``field`` (positive inside) with less than
    ``MIN_PIECE_FRACTION`` of the largest one's nodes; False when nothing is inside."""
    labels, count = ndimage.label(field > 0)
    if count == 0:
        return False
    sizes = np.bincount(labels.ravel())[1:]
    small = np.flatnonzero(sizes < MIN_PIECE_FRACTION * sizes.max()) + 1
    if len(small):
        field[np.isin(labels, small)] = -cell
    return True


def _drop_columns_seen_as_other(field: np.ndarray, view: CarveView,
                                world_from_pl: np.ndarray, xs: np.ndarray, ys: np.ndarray,
                                zs: np.ndarray, cell: float) -> np.ndarray:
    """``field`` (nx, ny, nz; plane frame, z up) without the columns whose highest node
    the camera saw as another object's surface (:func:`r2s.geometry.carving.seen_as_other`):
    nothing hides that node, so the column's top would have been seen as this object. What
    carving leaves of such a column is a layer within the sensor margin of the other
    object's surface (the convex footprint of a curved object, a banana, spans the plate
    it lies on, and is carved down to the plate's surface but not through it) and, below
    it, space inside the other object. Unchanged when every column would go."""
    inside = field > 0
    filled = inside.any(axis=2)
    if view.others_inner is None or not filled.any():
        return field
    top = inside.shape[2] - 1 - np.argmax(inside[:, :, ::-1], axis=2)
    ii, jj = np.nonzero(filled)
    nodes = np.c_[xs[ii], ys[jj], zs[top[ii, jj]]]
    seen = seen_as_other(view, transform_points(world_from_pl, nodes))
    if not seen.any() or seen.all():
        return field
    out = field.copy()
    out[ii[seen], jj[seen], :] = -cell
    return out if _drop_small_pieces(out, cell) else field
