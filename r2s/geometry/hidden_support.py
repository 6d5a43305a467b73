"""Where what an object lies on continues out of sight.

An object lying across others often hides the part of them it rests on: a toy lying over
the front of a drill hides the drill's chuck, a cup leaning on a block hides the block's
far half. A completion from the observation (a height field over the table) ends each
carrier where the carried object's mask begins. The carried object then touches it along
one edge only, its centre of mass lies past that edge, and it falls in the first check
of physopt, which moves it far from where it was seen to make it rest.

Given the first completions, for an object B whose centre of mass is not over the cells
where its base touches what is under it (other objects' tops, the table), and a
completed carrier A among those it touches, A's top is continued at the height of the
contact, from the contact towards B's centre of mass and ``PAST_M`` beyond it, no wider
across that direction than the contact, and only under B's base where it lies at that
height (within ``BASE_M``): the least continuation that carries B. It is kept only if it
does: B's centre of mass then lies over the contact cells with it. The points are A's
hidden top (:class:`r2s.geometry.hidden_carrier.HiddenTop`); completing A with them, the
carving against the depth image still removes whatever of it the camera saw past.

Frames: meshes and points are world; the grids live in the support plane's frame (z up
from the table).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import trimesh

from r2s.geometry.camera import transform_points
from r2s.geometry.completion import centre_over
from r2s.geometry.hidden_carrier import HiddenTop
from r2s.geometry.plane import world_from_plane
from r2s.geometry.sdf import raycasting_scene, vertical_heights

CELL_M = 0.002
"""Spacing of the grid of vertical rays under the carried object."""
CONTACT_M = 0.003
"""A cell where the carried object's base lies less than this above a carrier's top (or
the table), or sunk into it by less than four times this, is a contact."""
MIN_CONTACT_CELLS = 4
"""A carrier touched on fewer cells is not continued."""
BASE_M = 0.005
"""The continuation goes only where the carried object's base lies within this of the
contact's height."""
PAST_M = 0.01
"""The continuation reaches this far past the carried object's centre of mass."""


def _heights(mesh_plane: trimesh.Trimesh, xy: np.ndarray, from_above: bool) -> np.ndarray:
    """(M,) height of the first surface of ``mesh_plane`` (plane frame) met by vertical
    rays at ``xy`` (M, 2), from above (its top) or from below (its base); NaN where none."""
    scene = raycasting_scene(np.asarray(mesh_plane.vertices), np.asarray(mesh_plane.faces))
    lo, hi = mesh_plane.bounds[:, 2]
    return vertical_heights(scene, xy, hi + 1.0 if from_above else lo - 1.0, from_above)


def support_extension(carried_world: trimesh.Trimesh,
                      carriers_world: Mapping[int, trimesh.Trimesh],
                      others_world: Mapping[int, trimesh.Trimesh],
                      plane_point: np.ndarray, plane_normal: np.ndarray,
                      carried_id: int = 0) -> HiddenTop | None:
    """The least continuation of one carrier's top that carries ``carried_world``.

    carried_world : the carried object's closed mesh (world); carriers_world : id -> the
    meshes that may be continued (completed objects); others_world : id -> every other
    object's mesh that may carry it as it is (registered priors); plane_point,
    plane_normal : (3,) the support plane. Returns the carrier's :class:`HiddenTop` (world
    points on a ``CELL_M`` grid), or None when the object's centre of mass already lies
    over its contacts, or no single carrier's continuation puts it there.
    """
    world_from_pl = world_from_plane(plane_point, plane_normal)
    plane_from_world = np.linalg.inv(world_from_pl)
    carried = carried_world.copy().apply_transform(plane_from_world)
    (x0, y0, _), (x1, y1, _) = carried.bounds
    gx, gy = np.meshgrid(np.arange(x0, x1 + CELL_M / 2, CELL_M),
                         np.arange(y0, y1 + CELL_M / 2, CELL_M), indexing="ij")
    xy = np.c_[gx.ravel(), gy.ravel()]
    base = _heights(carried, xy, from_above=False)
    under = np.isfinite(base)
    xy, base = xy[under], base[under]
    com = np.asarray(carried.center_mass)[:2]
    contact = base < CONTACT_M  # on the table
    touching: dict[int, tuple[np.ndarray, float]] = {}
    for obj_id, mesh in {**others_world, **carriers_world}.items():
        local = mesh.copy().apply_transform(plane_from_world)
        (lx0, ly0, _), (lx1, ly1, _) = local.bounds
        if lx0 > x1 or lx1 < x0 or ly0 > y1 or ly1 < y0:
            continue  # nowhere under it
        top = _heights(local, xy, from_above=True)
        with np.errstate(invalid="ignore"):  # sunk into the top counts as touching it
            on = np.isfinite(top) & (base - top < CONTACT_M) & (base > top - 4 * CONTACT_M)
        contact |= on
        if obj_id in carriers_world and np.count_nonzero(on) >= MIN_CONTACT_CELLS:
            touching[obj_id] = (on, float(np.median(top[on])))
    if centre_over(xy[contact], com):
        return None
    best = None
    for obj_id, (on, height) in sorted(touching.items()):
        cells = _continuation(xy, base, on, height, com)
        if cells is None or not centre_over(np.concatenate([xy[contact], cells]), com):
            continue
        if best is None or len(cells) < len(best[2]):
            best = (obj_id, height, cells)
    if best is None:
        return None
    obj_id, height, cells = best
    points = transform_points(world_from_pl, np.c_[cells, np.full(len(cells), height)])
    return HiddenTop(carrier_id=obj_id, carried_id=carried_id, height_m=height,
                     points_world=points)


def _continuation(xy: np.ndarray, base: np.ndarray, on: np.ndarray, height: float,
                  com: np.ndarray) -> np.ndarray | None:
    """(K, 2) the cells (plane frame) continuing contact ``on`` (N,) bool of grid ``xy``
    (N, 2) towards ``com`` (2,): past the contact along the direction to ``com``, up to
    ``PAST_M`` beyond it, within the contact's width across, where the carried object's
    ``base`` (N,) lies within ``BASE_M`` of ``height``; None when there are none."""
    start = xy[on].mean(axis=0)
    towards = com - start
    reach = float(np.linalg.norm(towards))
    if reach < CELL_M:
        return None
    along_dir = towards / reach
    across_dir = np.array([-along_dir[1], along_dir[0]])
    along, across = xy @ along_dir, xy @ across_dir
    lo, hi = across[on].min(), across[on].max()
    keep = ((along > along[on].max()) & (along <= com @ along_dir + PAST_M)
            & (across >= lo) & (across <= hi) & (np.abs(base - height) < BASE_M))
    return xy[keep] if np.any(keep) else None
