"""How deep an object seen only as a face may run on behind it.

A completion from one view (a height field over the table) ends an object where its
observed points end. When the camera sees its top, that is where it ends; when something
nearer hides its top (a can lying over a box, a toy in front of a cube), only its front
face is seen, and the completion is a slab as thin as that face: standing on its edge, it
topples in physopt's first check, and whatever rests on it falls with it.

Nothing in the image says how deep such an object is, but a slab is the least likely
answer: objects on a table are rarely much thinner than they are wide. This module gives
the points of a *hidden back*: at the face's top height, over the strip behind the face
that runs away from the camera as far as the face is wide across the view (or as thick as
it was seen, if that is more). Completed with them, the object becomes a box as deep as it
is wide; the carving against the depth image still removes whatever of it the camera saw
past (the table behind it). It is made from the object's own view alone (the hidden space
other objects were given is not kept out; physopt cuts what overlaps), and it is an
alternative shape only (init keeps it in ``init/alternates/``): physopt swaps it in where
the first shape cannot rest near where it was seen, and keeps it only where the scene then
looks no worse (r2s/physopt/swap_choice.py).

Frames: points are world (3-D); the tests run in the support plane's frame (z up from the
table), "along" the horizontal direction from the camera to the object's points.
"""

from __future__ import annotations

import numpy as np

from r2s.geometry.camera import transform_points
from r2s.geometry.hidden_carrier import (MAX_THICKNESS_RATIO, TOP_PERCENTILE,
                                         points_above_table, view_axes)
from r2s.geometry.plane import world_from_plane

MIN_HEIGHT_M = 0.02
"""Lower faces are left alone: a slab this low does not topple."""
MIN_DEEPER_M = 0.01
"""The back must reach at least this much deeper than the face was seen."""


def hidden_back(points_world: np.ndarray, plane_point: np.ndarray, plane_normal: np.ndarray,
                eye_world: np.ndarray, cell_m: float = 0.003) -> np.ndarray | None:
    """(M, 3) world points on the top of the object's hidden back, or None when its points
    are not a face (they span, along the view, at least ``MAX_THICKNESS_RATIO`` of its
    height) or the back would add less than ``MIN_DEEPER_M``.

    points_world : (N, 3) the object's observed points, world frame; plane_point,
    plane_normal : (3,) the support plane (normal up); eye_world : (3,) the camera centre;
    cell_m : spacing of the points.
    """
    world_from_pl = world_from_plane(plane_point, plane_normal)
    plane_from_world = np.linalg.inv(world_from_pl)
    q = points_above_table(points_world, plane_from_world)
    if q is None:
        return None
    z_top = float(np.percentile(q[:, 2], TOP_PERCENTILE))
    if z_top < MIN_HEIGHT_M:
        return None
    eye = transform_points(plane_from_world, np.asarray(eye_world, dtype=np.float64)[None])[0]
    axes = view_axes(q, eye)
    if axes is None:
        return None  # straight above: the top is seen
    along_dir, across_dir = axes
    along, across = q[:, :2] @ along_dir, q[:, :2] @ across_dir
    near, far = float(np.percentile(along, 5)), float(np.percentile(along, 95))
    if far - near >= MAX_THICKNESS_RATIO * z_top:
        return None
    lo, hi = float(np.percentile(across, 2)), float(np.percentile(across, 98))
    depth = max(hi - lo, far - near)
    if near + depth - far < MIN_DEEPER_M:
        return None
    a = np.arange(float(np.median(along)), near + depth + cell_m / 2, cell_m)
    c = np.arange(lo, hi + cell_m / 2, cell_m)
    ga, gc = np.meshgrid(a, c, indexing="ij")
    xy = ga.ravel()[:, None] * along_dir + gc.ravel()[:, None] * across_dir
    return transform_points(world_from_pl, np.c_[xy, np.full(len(xy), z_top)])
