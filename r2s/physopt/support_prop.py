"""A hidden prop on an object, under a child that falls off it: a repair the camera cannot see.

An object seen resting on another is carried by the other's top, and that top is where the
camera sees least: the child hides it. A completed (or guessed) parent is often wrong
exactly there: a cup's rim under a box lying across it is not seen, so the completion has
no rim on that side, and the box tips into the cup or off it in the simulator. The
repairs that make it rest then carry it far from where it was seen (fresh9 scene_05:
43 mm, 44 deg).

The prop: the slice of the child's collision pieces ``slice_m`` above the lowest of their
points that lie over the parent's footprint (the parent's pieces projected along gravity),
clipped to that footprint, projected down to that lowest level (less ``gap_m``), and
extruded ``depth_m`` further down. It becomes one more convex piece of the *parent*, in
the parent's frame: a flat shelf the child already sits on, where the parent's top was
unseen. Columns of it the camera saw past (the observed depth lies behind one of its
points: ``hidden`` says no) are left out, so the prop never fills space seen empty. The
visual meshes are untouched.

Frames: pieces are in their object's frame; poses (4, 4) ``world_from_object``; ``up``
(3,) a unit vector in the world frame (against gravity); metres.
"""

from __future__ import annotations

from typing import Callable, Optional

import numpy as np
import trimesh
from scipy.spatial import Delaunay, QhullError

from r2s.geometry.camera import image_pixels, transform_points
from r2s.geometry.collision_trim import capped_hull
from r2s.physopt.piece_overlap import plane_crossings

SLICE_M = 0.003
"""The child's underside: its pieces' section this far above its lowest point over the
parent."""
DEPTH_M = 0.01
"""How far the prop reaches down from the child's underside."""
GAP_M = 5e-4
"""The prop's top lies this far below the child's lowest point (no initial overlap)."""
GRID_M = 0.002
"""Spacing of the columns the prop is built from (and tested for visibility)."""
MIN_AREA_M2 = 2e-5
"""A prop smaller than this (20 mm^2) is not made."""
SURFACE_SAMPLES = 2000
"""Points sampled on each of the child's pieces (with its corners) to find its lowest
point over the parent (fixed seed: the same pieces give the same prop)."""
FALL_DEG = 30.0
"""A child falls in a check when it turns this much (or moves the judge's translation)."""



def fell(drift: tuple[float, float], judge_translation_m: float) -> bool:
    """Whether a check's ``drift`` (COM translation m, rotation deg) is a fall: the judge's
    translation, or ``FALL_DEG``."""
    return drift[0] >= judge_translation_m or drift[1] >= FALL_DEG


Hidden = Callable[[np.ndarray], np.ndarray]
"""``hidden(points_world)`` (N, 3) -> (N,) bool: the camera did not see past the point."""


def _plane_basis(up: np.ndarray) -> np.ndarray:
    """(2, 3) two unit vectors spanning the plane normal to ``up``."""
    seed = np.eye(3)[int(np.argmin(np.abs(up)))]
    a = np.cross(up, seed)
    a /= np.linalg.norm(a)
    return np.stack([a, np.cross(up, a)])


def _inside(polygon_points_2d: np.ndarray, query_2d: np.ndarray) -> np.ndarray:
    """(M,) bool: ``query_2d`` inside the convex hull of ``polygon_points_2d``."""
    try:
        return Delaunay(polygon_points_2d).find_simplex(query_2d) >= 0
    except (QhullError, ValueError):
        return np.zeros(len(query_2d), dtype=bool)


def _world(pieces: list[trimesh.Trimesh], pose: np.ndarray) -> list[np.ndarray]:
    return [transform_points(pose, np.asarray(p.vertices, dtype=np.float64)) for p in pieces]


def prop_points_world(child_pieces: list[trimesh.Trimesh], child_pose: np.ndarray,
                      parent_pieces: list[trimesh.Trimesh], parent_pose: np.ndarray,
                      up: np.ndarray, hidden: Optional[Hidden] = None,
                      slice_m: float = SLICE_M, depth_m: float = DEPTH_M,
                      gap_m: float = GAP_M) -> Optional[np.ndarray]:
    """(K, 3) world corners of the prop (module docstring), or None when the child's
    underside does not lie over the parent, or the part of it the camera did not see past
    is smaller than ``MIN_AREA_M2``."""
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    basis = _plane_basis(up)
    parent_2d = np.vstack(_world(parent_pieces, parent_pose)) @ basis.T
    child_world = _world(child_pieces, child_pose)
    surface = np.vstack([np.vstack([v, transform_points(child_pose, trimesh.sample.sample_surface(
        piece, SURFACE_SAMPLES, seed=0)[0])]) for piece, v in zip(child_pieces, child_world)])
    over = surface[_inside(parent_2d, surface @ basis.T)]
    if not len(over):
        return None
    low = float((over @ up).min())
    section = []
    for piece, v in zip(child_pieces, child_world):
        h = v @ up
        if h.min() > low + slice_m or h.max() <= low + slice_m:
            continue
        world_piece = trimesh.Trimesh(v, piece.faces, process=False)
        section.append(plane_crossings(world_piece, h - (low + slice_m)))
    if not section or sum(len(s) for s in section) < 3:
        return None
    section_2d = np.vstack(section) @ basis.T
    lo, hi = section_2d.min(axis=0), section_2d.max(axis=0)
    grid = np.stack(np.meshgrid(np.arange(lo[0], hi[0] + GRID_M, GRID_M),
                                np.arange(lo[1], hi[1] + GRID_M, GRID_M)), -1).reshape(-1, 2)
    grid = grid[_inside(section_2d, grid) & _inside(parent_2d, grid)]
    if len(grid) < 3:
        return None
    top = grid @ basis + up * (low - gap_m)
    bottom = top - up * depth_m
    if hidden is not None:
        keep = hidden(top) & hidden(bottom)
        top, bottom = top[keep], bottom[keep]
    if len(top) * GRID_M ** 2 < MIN_AREA_M2:
        return None
    return np.vstack([top, bottom])


def with_prop(child_pieces: list[trimesh.Trimesh], child_pose: np.ndarray,
              parent_pieces: list[trimesh.Trimesh], parent_pose: np.ndarray,
              up: np.ndarray, hidden: Optional[Hidden] = None
              ) -> tuple[list[trimesh.Trimesh], float]:
    """The parent's pieces with the prop (module docstring) appended, in the parent's
    frame, and the prop's top area in m^2; the parent's pieces unchanged (same list) and 0
    when no prop is made."""
    corners = prop_points_world(child_pieces, child_pose, parent_pieces, parent_pose, up,
                                hidden)
    if corners is None:
        return parent_pieces, 0.0
    hull = capped_hull(transform_points(np.linalg.inv(parent_pose), corners))
    if hull is None:
        return parent_pieces, 0.0
    up_parent = np.asarray(parent_pose, dtype=np.float64)[:3, :3].T @ (
        np.asarray(up, dtype=np.float64) / np.linalg.norm(up))
    area = float(hull.area_faces[(hull.face_normals @ up_parent) > 0.999].sum())
    return [*parent_pieces, hull], area


def depth_hidden(depth_m: np.ndarray, K: np.ndarray, world_from_camera: np.ndarray,
                 margin_m: float = 0.003) -> Hidden:
    """``hidden`` from an observed depth image (H, W) in metres (NaN: no reading): a point
    is hidden where the camera saw something at least ``margin_m`` in front of it, where it
    has no reading, or outside the image; it is seen past (not hidden) where the observed
    depth reaches it or lies behind it."""
    h, w = depth_m.shape

    def hidden(points_world: np.ndarray) -> np.ndarray:
        ok, row, col, _, z = image_pixels(points_world, K, world_from_camera, h, w)
        seen = depth_m[row, col]
        return ~ok | ~np.isfinite(seen) | (seen < z - margin_m)

    return hidden
