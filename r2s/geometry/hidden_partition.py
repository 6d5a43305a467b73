"""Who owns hidden space that two completed objects both claim.

Completion without a prior fills what the camera could not see (below the visible surface,
behind nearer things) with material, object by object. Two objects side by side, or one
partly under the overhang of another, can then both fill the same hidden space: the
completed shapes interpenetrate by centimetres, and the physics stages push them apart,
far from where the camera saw them. The observation does not say whose the space is, so
it goes to the object whose *observed surface* is nearer (a Voronoi split of the hidden
space by the seen surfaces). A registered prior is a whole shape: space inside a prior is
never another object's.

:func:`exclusion` builds the test a completion applies to its grid nodes (world frame).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import open3d as o3d
import trimesh
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class Claimant:
    """Another object that may claim hidden space.

    mesh_world : its closed mesh, world frame; points_world : (N, 3) its observed points
    (empty for none); is_prior : its shape is a registered prior (it owns all its inside).
    """

    mesh_world: trimesh.Trimesh
    points_world: np.ndarray
    is_prior: bool = False


def _occupancy(mesh: trimesh.Trimesh) -> Callable[[np.ndarray], np.ndarray]:
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32)),
                        o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)))
    lo, hi = mesh.bounds

    def inside(points: np.ndarray) -> np.ndarray:
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        out = np.zeros(len(pts), dtype=bool)
        near = np.all((pts >= lo) & (pts <= hi), axis=1)
        if near.any():
            q = o3d.core.Tensor(pts[near].astype(np.float32))
            out[near] = scene.compute_occupancy(q, nsamples=3).numpy() > 0.5
        return out

    return inside


def overlaps(mesh_world: trimesh.Trimesh, others: Sequence[Claimant],
             min_fraction: float = 0.01) -> bool:
    """Whether at least ``min_fraction`` of ``mesh_world``'s vertices lie inside another
    claimant's mesh."""
    verts = np.asarray(mesh_world.vertices)
    if not len(verts):
        return False
    hit = np.zeros(len(verts), dtype=bool)
    for other in others:
        hit |= _occupancy(other.mesh_world)(verts)
    return float(hit.mean()) >= min_fraction


def exclusion(own_points_world: np.ndarray, others: Sequence[Claimant]
              ) -> Callable[[np.ndarray], np.ndarray]:
    """``f(nodes (M, 3) world) -> (M,) bool``: nodes inside another claimant's mesh that
    belong to it: it is a prior, or its observed points are nearer than this object's."""
    own_tree = cKDTree(np.asarray(own_points_world, dtype=np.float64).reshape(-1, 3))
    tests = [(_occupancy(o.mesh_world), o.is_prior,
              cKDTree(o.points_world) if len(o.points_world) else None) for o in others]

    def excluded(nodes: np.ndarray) -> np.ndarray:
        pts = np.asarray(nodes, dtype=np.float64).reshape(-1, 3)
        out = np.zeros(len(pts), dtype=bool)
        own_d = None
        for inside, is_prior, tree in tests:
            hit = inside(pts) & ~out
            if not hit.any():
                continue
            if is_prior or tree is None:
                out |= hit
                continue
            if own_d is None:
                own_d = own_tree.query(pts)[0]
            idx = np.flatnonzero(hit)
            other_d = tree.query(pts[idx])[0]
            out[idx[other_d < own_d[idx]]] = True
        return out

    return excluded
