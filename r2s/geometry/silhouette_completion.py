"""Complete an object whose mask has (almost) no depth reading, from its silhouette alone.

Transparent, black and mirror-like objects can read no depth at all on a RealSense-class
sensor, yet their mask says where they are in the image, the support plane says where the
table is, and the depth around them says where they are not. Leaving such an object out
leaves a hole in the twin that a robot would drive through. The solid is built on a grid
in the support plane's frame (z up) from three facts and one guess:

1. *It stands on what is seen just below it* in the image: the table, or the top of the
   object it sits on (the median height of the readings a few pixels below the mask's
   lower outline, :func:`_base_height`). Every ray through the mask meets that level
   somewhere behind the object; those points form the object's "shadow" seen from the
   camera (its footprint and what it hides). The near edge of the shadow is the front of
   its base, where the object meets its support in view: in every strip along the
   horizontal viewing direction, the shadow's nearest point.
2. *It lies inside its visual cone.* A node is kept only where it projects into the mask
   (grown by ``mask_grow_px``) or behind something nearer (another object's reading in
   front of it, :func:`r2s.geometry.carving.hidden_by_other`: an occluded base).
3. *Nothing where the camera saw past* (:func:`r2s.geometry.carving.seen_free`, the table
   exact when the view has the plane), nor inside the objects that were seen (``exclude``):
   a guess gives way to what was measured.
4. *The guess:* from its front edge the object reaches back along the view as far as it
   is wide across it (a round or a square object), never beyond its shadow; and its top
   is where the strip's highest mask ray (the one that meets the table farthest) passes
   over that back edge. One view cannot tell a tall object from a deep one; this guess
   makes the choice a box or a can would. A strip whose rays first meet the support behind
   the middle of the object (its front plus half its width) shows no front of a base
   there but a part above the support that overhangs it (a duck's head, a mug's handle):
   its column starts at the object's front, where the body is.

The result is a plausible body where the image shows the object, not a measurement: init
gives it ``source="silhouette"`` and a warning line, and its shape should not be trusted
for anything finer than collision avoidance.

Frames: pixels are ``(row, col)``; world points use ``world_from_camera`` (OpenCV camera);
the plane frame is :func:`r2s.geometry.plane.world_from_plane`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy import ndimage

from r2s.geometry.camera import backproject, image_pixels, project, transform_points
from r2s.geometry.carving import CarveView, hidden_by_other, seen_free
from r2s.geometry.completion import CompletedShape, mesh_field
from r2s.geometry.plane import world_from_plane

MIN_RAYS = 20
"""Fewer mask rays that reach the table than this: nothing to stand on (``ValueError``)."""

MASK_GROW_PX = 1
MIN_FRONT_OVER_LIFT = 0.25
"""The object's front must lie at least this many times the camera's height away
(horizontally), i.e. be seen less than about 76 deg below the horizon: from nearly straight
above a silhouette shows the object's top outline only, and the guess of its height from
the rays over its back fails (a 100 mm glass came out 177-321 mm tall)."""
WIDTH_PERCENTILES = (2.0, 98.0)
"""The object's width across the view: this range of its rays' bearings, at the distance
of its front (a few stray mask pixels do not widen it)."""


def complete_from_silhouette(mask: np.ndarray, K: np.ndarray, world_from_camera: np.ndarray,
                             plane_point: np.ndarray, plane_normal: np.ndarray,
                             view: CarveView | None = None, cell_m: float = 0.003,
                             max_cells: int = 100, max_height_m: float = 0.5,
                             mask_grow_px: int = MASK_GROW_PX,
                             color: np.ndarray | None = None,
                             exclude: Callable[[np.ndarray], np.ndarray] | None = None
                             ) -> CompletedShape:
    """A closed mesh of an object seen only as a mask, standing on the support plane.

    Parameters
    ----------
    mask : (H, W) bool, the object's instance mask.
    K : (3, 3) intrinsics; world_from_camera : (4, 4) OpenCV camera to world.
    plane_point, plane_normal : (3,) the support plane, world frame (normal up, towards
        the camera).
    view : the depth view to carve against (its ``own`` pixels the mask's), or None.
    cell_m : grid cell (grown so no side has more than ``max_cells`` cells).
    max_height_m : the tallest object considered.
    color : (3,) uint8 colour of the mesh, or None.
    exclude : world points (M, 3) -> (M,) bool, space other objects fill (they were seen;
        this one was not), removed like free space.

    Returns
    -------
    :class:`CompletedShape` (object frame: the plane's axes, origin at the footprint's
    centre on the base); ``ValueError`` when the mask's rays do not reach the table in
    front of the camera or nothing is left after carving.
    """
    m = np.asarray(mask, dtype=bool)
    world_from_pl = world_from_plane(plane_point, plane_normal)
    pl_from_world = np.linalg.inv(world_from_pl)
    wfc = np.asarray(world_from_camera, dtype=np.float64)
    eye = transform_points(pl_from_world, wfc[:3, 3][None])[0]
    base = _base_height(m, view, K, wfc, world_from_pl) if view is not None else 0.0
    lift = eye[2] - base  # the camera's height over the surface the object stands on
    if lift <= 0:
        raise ValueError("the camera is not above the surface the object stands on")
    rows, cols = np.nonzero(m)
    rays_cam = np.linalg.solve(np.asarray(K, dtype=np.float64),
                               np.stack([cols + 0.0, rows + 0.0, np.ones(len(rows))]))
    rays = (pl_from_world[:3, :3] @ wfc[:3, :3] @ rays_cam).T
    down = rays[:, 2] < -1e-9
    if np.count_nonzero(down) < MIN_RAYS:
        raise ValueError("too few of the mask's rays reach the table")
    ground = eye[:2] + (-lift / rays[down, 2])[:, None] * rays[down, :2]

    fp = _footprint(ground, eye[:2], lift, cell_m, max_cells)
    cell = fp.cell
    slope = -rays[down, 2] / np.linalg.norm(rays[down, :2], axis=1)  # drop per metre
    top = float(np.clip(np.max(lift - slope * fp.near[np.isfinite(fp.near)].min()), 2 * cell,
                        max_height_m))
    xs, ys, column, cap = _columns(fp, eye[:2])
    zs = base + np.arange(0.5 * cell, top + cell, cell)
    if not column.any():
        raise ValueError("the mask gives no footprint on the table")

    grown = ndimage.binary_dilation(m, iterations=mask_grow_px) if mask_grow_px > 0 else m
    field = _carved_field(xs, ys, zs, column, cap, base, grown, K, wfc, world_from_pl,
                          view, exclude, cell)
    # the lowest layer of nodes is half a cell up: with the outside layer mesh_field pads
    # below it, the base comes out on the plane
    mesh, centre = mesh_field(field, np.array([xs[0], ys[0], zs[0]]), cell)
    if color is not None:
        rgba = np.append(np.asarray(color, dtype=np.uint8)[:3], 255)
        mesh.visual.vertex_colors = np.tile(rgba, (len(mesh.vertices), 1))
    plane_from_object = np.eye(4)
    plane_from_object[:3, 3] = centre
    return CompletedShape(mesh=mesh, world_from_object=world_from_pl @ plane_from_object,
                          bottom_m=float(centre[2]))


@dataclass(frozen=True)
class _Footprint:
    """The guessed footprint in strips of equal bearing from the camera (plane frame).

    forward, across : (2,) unit vectors, the horizontal view and across it; b_lo, b_hi,
    step : the bearings (across / forward distance) the strips span and the bearing per
    strip;
    near, back : (S,) each strip's front and back edge (forward distance, m; inf / -inf
    for an empty strip); height : (S,) each strip's height (m); cell : the grid cell (m).
    """

    forward: np.ndarray
    across: np.ndarray
    b_lo: float
    b_hi: float
    step: float
    near: np.ndarray
    back: np.ndarray
    height: np.ndarray
    cell: float


def _footprint(ground: np.ndarray, eye_xy: np.ndarray, lift: float, cell_m: float,
               max_cells: int) -> _Footprint:
    """Steps 1 and 4 of the module docstring from ``ground`` ((N, 2) where the mask's rays
    meet the support level, plane frame), the camera's position ``eye_xy`` (2,) and height
    ``lift`` over that level."""
    forward = ground.mean(axis=0) - eye_xy
    if np.linalg.norm(forward) < 1e-9:
        forward = np.array([1.0, 0.0])  # camera straight above: any direction will do
    forward /= np.linalg.norm(forward)
    across = np.array([-forward[1], forward[0]])
    s = (ground - eye_xy) @ forward
    # strips of equal bearing from the camera (the shadow fans out behind the object; a
    # bearing is the same at the object's front and at the shadow's far end)
    bearing = ((ground - eye_xy) @ across) / s
    b_lo, b_hi = np.percentile(bearing, WIDTH_PERCENTILES)
    s_front = float(np.percentile(s, WIDTH_PERCENTILES[0]))
    if s_front < MIN_FRONT_OVER_LIFT * lift:
        raise ValueError("seen from nearly straight above, its height cannot be told from "
                         "its silhouette")
    width = max(float(b_hi - b_lo) * s_front, cell_m)  # across the view at its front
    cell = max(cell_m, max(width, float(s.max() - s.min())) / max_cells)
    step = cell / s_front
    n_strips = int(np.ceil((b_hi - b_lo) / step)) + 1
    strips = np.floor((bearing - b_lo) / step).astype(int)
    in_range = (strips >= 0) & (strips < n_strips)
    near = np.full(n_strips, np.inf)
    far = np.full(n_strips, -np.inf)
    np.minimum.at(near, strips[in_range], s[in_range])
    np.maximum.at(far, strips[in_range], s[in_range])
    # A strip whose mask rays first meet the support behind the object's middle does not
    # show the front of its base there: it shows a part that overhangs, above the support
    # (a duck's head, a mug's handle, an end lying on something). Its column goes where
    # the body is, from the front of the object, not a whole width behind that point.
    overhang = np.isfinite(near) & (near > s_front + 0.5 * width)
    near[overhang] = s_front
    back = np.minimum(near + width, far)  # as deep as wide, within the shadow
    # the ray that meets the support farthest in a strip grazes the top of the object's
    # back: the strip's height is that ray's height above the back edge
    with np.errstate(invalid="ignore", divide="ignore"):
        height = np.where(far > 0, lift * (far - back) / far, 0.0)
    return _Footprint(forward, across, float(b_lo), float(b_hi), float(step), near, back,
                      height, cell)


def _columns(fp: _Footprint, eye_xy: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The grid over the footprint's bounding box (plane frame): node coordinates xs (nx,),
    ys (ny,), which columns are in the footprint (nx, ny) and each column's height (m)."""
    cell, ok = fp.cell, np.isfinite(fp.near)
    corners = [eye_xy + dist * (fp.forward + bear * fp.across)
               for dist in (fp.near[ok].min(), fp.back[ok].max())
               for bear in (fp.b_lo, fp.b_hi + fp.step)]
    lo = np.min(corners, axis=0) - cell
    hi = np.max(corners, axis=0) + cell
    xs = np.arange(lo[0], hi[0] + cell, cell)
    ys = np.arange(lo[1], hi[1] + cell, cell)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    rel = np.stack([gx - eye_xy[0], gy - eye_xy[1]], axis=-1)
    gs = rel @ fp.forward
    with np.errstate(invalid="ignore", divide="ignore"):
        strip = np.floor(((rel @ fp.across) / gs - fp.b_lo) / fp.step).astype(int)
    valid = (gs > 0) & (strip >= 0) & (strip < len(fp.near))
    strip = np.clip(strip, 0, len(fp.near) - 1)
    column = valid & (gs >= fp.near[strip]) & (gs <= fp.back[strip])
    return xs, ys, column, np.maximum(fp.height[strip], 2 * cell)


def _carved_field(xs: np.ndarray, ys: np.ndarray, zs: np.ndarray, column: np.ndarray,
                  cap: np.ndarray, base: float, mask: np.ndarray, K: np.ndarray,
                  world_from_camera: np.ndarray, world_from_pl: np.ndarray,
                  view: CarveView | None,
                  exclude: Callable[[np.ndarray], np.ndarray] | None, cell: float
                  ) -> np.ndarray:
    """Steps 2 and 3 of the module docstring: (nx, ny, nz) field, ``cell`` inside and
    ``-cell`` outside, of the grid nodes (plane frame ``xs``, ``ys``, ``zs``) in the
    footprint's ``column``s up to their ``cap`` (nx, ny; height over ``base``, the support
    level, m) that project into ``mask`` or behind a nearer object, are not seen free and
    not excluded; its largest connected piece."""
    ci, cj = np.nonzero(column)
    nodes_pl = np.stack([np.repeat(xs[ci], len(zs)), np.repeat(ys[cj], len(zs)),
                         np.tile(zs, len(ci))], axis=1)
    nodes_w = transform_points(world_from_pl, nodes_pl)
    below_top = nodes_pl[:, 2] - base <= np.repeat(cap[ci, cj], len(zs)) + 0.5 * cell
    inside = below_top & _in_mask(mask, nodes_w, K, world_from_camera)
    if view is not None:
        inside |= below_top & hidden_by_other(view, nodes_w)
        inside &= ~seen_free(view, nodes_w)
    if exclude is not None and inside.any():
        inside[inside] = ~exclude(nodes_w[inside])
    field = np.full((len(xs), len(ys), len(zs)), -cell)
    flat = inside.reshape(len(ci), len(zs))
    field[ci[:, None], cj[:, None], np.arange(len(zs))[None, :]] = np.where(flat, cell, -cell)
    labels, count = ndimage.label(field > 0)
    if count == 0:
        raise ValueError("nothing of the visual cone is left after carving")
    sizes = np.bincount(labels.ravel())[1:]
    field[(labels != 1 + int(np.argmax(sizes))) & (field > 0)] = -cell
    return field


BELOW_PX = 4
"""How far below the mask's lower outline (along the image's downward direction) the
surface the object stands on is read."""


def _base_height(mask: np.ndarray, view: CarveView, K: np.ndarray, world_from_camera: np.ndarray,
                 world_from_pl: np.ndarray) -> float:
    """Height (m, plane frame) of the surface the object stands on: the median height of
    the valid readings just below its mask's lower outline (the table, or the top of the
    object it sits on); 0 when fewer than ``MIN_RAYS`` are read there."""
    rows, cols = np.nonzero(mask)
    pl_from_world = np.linalg.inv(world_from_pl)
    # the image's downward direction at the mask: where a point 5 cm below one on its
    # central ray projects (an upright camera: +v; a rolled one: tilted)
    centre = np.array([cols.mean(), rows.mean(), 1.0])
    ray = world_from_camera[:3, :3] @ np.linalg.solve(K, centre)
    point = world_from_camera[:3, 3] + 0.5 * ray / np.linalg.norm(ray)
    (u0, v0), (u1, v1) = project(np.stack([point, point - 0.05 * world_from_pl[:3, 2]]), K,
                                 world_from_camera)[0]
    step = np.array([v1 - v0, u1 - u0])
    if not np.all(np.isfinite(step)) or np.linalg.norm(step) < 1e-9:
        return 0.0
    step /= np.linalg.norm(step)
    height, width = mask.shape
    below = np.zeros_like(mask)
    for k in range(1, BELOW_PX + 1):
        r = np.rint(rows + k * step[0]).astype(int)
        c = np.rint(cols + k * step[1]).astype(int)
        ok = (r >= 0) & (r < height) & (c >= 0) & (c < width)
        below[r[ok], c[ok]] = True
    depth = view.depth_m
    below &= ~mask & np.isfinite(depth) & (depth > 0)
    if np.count_nonzero(below) < MIN_RAYS:
        return 0.0
    pts = backproject(np.where(below, depth, np.nan), K, world_from_camera)
    return max(0.0, float(np.median(transform_points(pl_from_world, pts)[:, 2])))


def _in_mask(mask: np.ndarray, points_world: np.ndarray, K: np.ndarray,
             world_from_camera: np.ndarray) -> np.ndarray:
    """(N,) bool: world points (N, 3) in front of the camera that project into ``mask``."""
    ok, row, col, _, _ = image_pixels(points_world, K, world_from_camera, *mask.shape)
    return ok & mask[row, col]
