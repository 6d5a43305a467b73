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

from dataclasses import dataclass, field
from typing import Callable, Optional, Sequence

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from r2s.geometry.sdf import occupancy, raycasting_scene


@dataclass(frozen=True)
class Claimant:
    """Another object that may claim hidden space.

    mesh_world : its closed mesh, world frame; points_world : (N, 3) its observed points
    (empty for none); is_prior : its shape is a registered prior (it owns all its inside).
    Its inside test and the search tree of its points are built once, on creation, and
    serve every object that asks.
    """

    mesh_world: trimesh.Trimesh
    points_world: np.ndarray
    is_prior: bool = False
    _scene: object = field(init=False, repr=False, compare=False)
    _tree: Optional[cKDTree] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_scene", raycasting_scene(self.mesh_world.vertices,
                                                            self.mesh_world.faces))
        pts = np.asarray(self.points_world, dtype=np.float64).reshape(-1, 3)
        object.__setattr__(self, "_tree", cKDTree(pts) if len(pts) else None)

    @property
    def has_points(self) -> bool:
        return self._tree is not None

    def inside(self, points: np.ndarray) -> np.ndarray:
        """(M,) bool: world points (M, 3) inside the mesh."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        lo, hi = self.mesh_world.bounds
        out = np.zeros(len(pts), dtype=bool)
        near = np.all((pts >= lo) & (pts <= hi), axis=1)
        if near.any():
            out[near] = occupancy(self._scene, pts[near])
        return out

    def distance_m(self, points: np.ndarray) -> np.ndarray:
        """(M,) distance of world points (M, 3) to its nearest observed point."""
        return self._tree.query(np.asarray(points, dtype=np.float64).reshape(-1, 3))[0]


def overlaps(mesh_world: trimesh.Trimesh, others: Sequence[Claimant],
             min_fraction: float = 0.01) -> bool:
    """Whether at least ``min_fraction`` of ``mesh_world``'s vertices lie inside another
    claimant's mesh."""
    verts = np.asarray(mesh_world.vertices)
    if not len(verts):
        return False
    hit = np.zeros(len(verts), dtype=bool)
    for other in others:
        hit |= other.inside(verts)
    return float(hit.mean()) >= min_fraction


def exclusion(own_points_world: np.ndarray, others: Sequence[Claimant]
              ) -> Callable[[np.ndarray], np.ndarray]:
    """``f(nodes (M, 3) world) -> (M,) bool``: nodes inside another claimant's mesh that
    belong to it: it is a prior, or its observed points are nearer than this object's."""
    own_tree = cKDTree(np.asarray(own_points_world, dtype=np.float64).reshape(-1, 3))

    def excluded(nodes: np.ndarray) -> np.ndarray:
        pts = np.asarray(nodes, dtype=np.float64).reshape(-1, 3)
        out = np.zeros(len(pts), dtype=bool)
        own_d = None
        for other in others:
            hit = other.inside(pts) & ~out
            if not hit.any():
                continue
            if other.is_prior or not other.has_points:
                out |= hit
                continue
            if own_d is None:
                own_d = own_tree.query(pts)[0]
            idx = np.flatnonzero(hit)
            out[idx[other.distance_m(pts[idx]) < own_d[idx]]] = True
        return out

    return excluded
