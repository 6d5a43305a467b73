"""Hidden overlap between two whole shapes, given to one of them.

Two registered priors are whole shapes, each with its own error: a single-image 3D model
is a few millimetres to centimetres off behind what the camera saw. Two such shapes can
then overlap where the camera cannot see (the back of one fruit inside the next). The
optimisation stages treat shapes as rigid, so they push the two apart until the overlap
is gone, and both leave where the camera saw them (on the seed demo scene, 10-24 mm,
docs/realistic.md). The camera says nothing about whose the hidden space is, so here each
overlap goes to the object whose *observed surface* is nearer to it (the rule
:mod:`r2s.geometry.hidden_partition` applies to completions), and the other object's
surface there is moved onto the owner's: each vertex of the yielding mesh inside the
owner is moved to its closest point on the owner's surface, plus a clearance, or, where
that surface faces away from the yielding object (the underside of a plate's thin floor
under a fruit sunk into it), to where the ray towards the yielding object's centre leaves
the owner. The rendered image does not change
(the moved surface was inside the other object, so hidden by it, or by whatever hid the
overlap), the shapes touch along the owner's surface and no longer overlap, up to the
spacing of the yielding mesh's vertices.

Frames: every mesh and point is in the world frame, metres.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Mapping

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from r2s.geometry.sdf import (closest_surface_points, decimated, first_hit_distance,
                              occupancy, raycasting_scene, winding_number)

CLEARANCE_M = 5e-4
"""A yielding vertex ends this far outside the owner's surface."""

MIN_DEPTH_M = 5e-4
"""A vertex less than this inside another shape is left alone (touching, not overlapping)."""

NEAR_FACE_M = 2e-3
"""Within this of an open mesh's surface, behind its closest face counts as inside."""

WINDING_FACES = 2000
"""Farther in, an open mesh decimated to this many faces gives the winding number."""

SHAPE_ERROR_M = 0.005
"""Shapes yield only in a scene where some two of them overlap by at least this: priors
that agree better (the YCB benchmark's meshes, registered within a few millimetres) are
exact, and their overlaps are pose errors that geomopt's small moves remove; the seed
demo's SAM 3D priors overlap by up to 16 mm. Measured in docs/realistic.md."""

MAX_DEPTH_M = 0.03
"""A vertex deeper than this inside another shape is not moved: the overlap is a gross
registration error, not a hidden-side shape error, and is left to the later stages."""

MAX_LIFT_M = 0.005
"""A prior reaching at most this far below the table has that part lifted onto it; one
deeper was registered too low (on the YCB check, a padlock 23 mm into the table; on the
seed demo the priors reach 1.4 and 3.0 mm); it also takes no part in the overlaps
(:func:`sunk_too_far`)."""

MAX_DENT_FRACTION = 0.3
"""Nor is a pair's overlap given up when it would dent the yielding shape by more than
this fraction of its thickness (the smallest extent of its oriented box): a 17 mm
overlap on an 18 mm marker means one of the two is in the wrong place. The seed demo's
deepest pair overlap, 16 mm on a 71 mm fruit, is 0.23."""


class _Surface:
    """One mesh (world frame) with what the tests ask of it, each built once: its
    ray-casting scene, whether it is closed, its decimated copy for winding numbers, its
    thickness."""

    def __init__(self, mesh: trimesh.Trimesh):
        self.mesh = mesh

    @functools.cached_property
    def scene(self):
        return raycasting_scene(self.mesh.vertices, self.mesh.faces)

    @functools.cached_property
    def closed(self) -> bool:
        return bool(trimesh.Trimesh(self.mesh.vertices, self.mesh.faces).is_watertight)

    @functools.cached_property
    def decimated(self) -> tuple[np.ndarray, np.ndarray]:
        return decimated(self.mesh, WINDING_FACES)

    @functools.cached_property
    def thickness_m(self) -> float:
        """The smallest extent of the mesh's oriented bounding box (m)."""
        return float(np.min(self.mesh.bounding_box_oriented.primitive.extents))


@dataclass(frozen=True)
class YieldReport:
    """What :func:`yield_hidden_overlaps` did to one mesh: vertices moved, the deepest of
    them (m) and the ids of the shapes it yielded to."""

    moved: int
    deepest_m: float
    yielded_to: tuple[int, ...]

    def as_dict(self) -> dict:
        return {"moved_vertices": self.moved, "deepest_mm": round(1000 * self.deepest_m, 2),
                "yielded_to": list(self.yielded_to)}


def yield_hidden_overlaps(meshes_world: Mapping[int, trimesh.Trimesh],
                          points_world: Mapping[int, np.ndarray],
                          clearance_m: float = CLEARANCE_M,
                          min_overlap_m: float = SHAPE_ERROR_M
                          ) -> tuple[dict[int, np.ndarray], dict[int, YieldReport], float]:
    """Per mesh that yields somewhere, its new vertices (V, 3) world (same order as its
    ``vertices``) and a report (meshes that keep their shape are absent); and the deepest
    overlap of a pair found (m). Nothing yields unless that reaches ``min_overlap_m``:
    shapes that agree that well are taken as exact, and their small overlaps as pose
    errors for geomopt.

    ``meshes_world``: id -> closed mesh; ``points_world``: id -> (N, 3) its observed points
    (may be empty: such a shape yields to one that has points). Each overlapping pair's
    overlap (the vertices of each inside the other) goes as a whole to the shape whose
    observed points are nearer to it (median distance): deciding vertex by vertex would
    hand each side's far rim to the other and open a gap. Every move is decided against
    the original shapes, so the result does not depend on the order of the ids."""
    ids = sorted(meshes_world)
    trees = {i: cKDTree(np.asarray(points_world[i], dtype=np.float64).reshape(-1, 3))
             for i in ids if len(np.asarray(points_world.get(i, ())).reshape(-1, 3))}
    faces = {i: np.asarray(meshes_world[i].faces) for i in ids}
    centres = {i: (trees[i].data.mean(axis=0) if i in trees
                   else np.asarray(meshes_world[i].vertices).mean(axis=0)) for i in ids}
    verts = {i: np.asarray(meshes_world[i].vertices, dtype=np.float64) for i in ids}
    out = {i: v.copy() for i, v in verts.items()}
    moved = {i: np.zeros(len(v), dtype=bool) for i, v in verts.items()}
    deepest = {i: 0.0 for i in ids}
    owners: dict[int, list[int]] = {i: [] for i in ids}

    def give(loser: int, owner: int, hit, owner_surface: _Surface | None) -> None:
        """Move the loser's vertices in ``hit`` out of the owner: by :func:`_way_out`
        (``owner_surface`` given), or to the closest surface point."""
        idx, depth, closest, normal = hit
        out[loser][idx] = (closest + clearance_m * normal if owner_surface is None else
                           _way_out(owner_surface, out[loser][idx], centres[loser], closest,
                                    normal, clearance_m))
        moved[loser][idx] = True
        deepest[loser] = max(deepest[loser], float(depth.max()))
        if owner not in owners[loser]:
            owners[loser].append(owner)

    pairs = [(a, b) for k, a in enumerate(ids) for b in ids[k + 1:]
             if _boxes_meet(meshes_world[a].bounds, meshes_world[b].bounds)]
    surfaces = {i: _Surface(meshes_world[i]) for i in ids}
    hits = {(a, b): (_inside(surfaces[b], verts[a]), _inside(surfaces[a], verts[b]))
            for a, b in pairs}
    overlap_m = max([float(h[1].max()) for both in hits.values() for h in both
                     if h is not None], default=0.0)
    if overlap_m < min_overlap_m:
        return {}, {}, overlap_m
    decided = []
    for (a, b), (a_in, b_in) in hits.items():
        if a_in is None and b_in is None:
            continue
        lens = np.concatenate([verts[a][a_in[0]] if a_in else np.zeros((0, 3)),
                               verts[b][b_in[0]] if b_in else np.zeros((0, 3))])
        owner, loser = (a, b) if _first_owns(lens, trees.get(a), trees.get(b)) else (b, a)
        hit = b_in if loser == b else a_in
        if hit is not None:
            if float(hit[1].max()) > MAX_DENT_FRACTION * surfaces[loser].thickness_m:
                continue  # a gross registration error, not a hidden-side shape error
            give(loser, owner, hit, surfaces[owner])
        decided.append((owner, loser))
    # what the yielding surface cannot take away (a thin part of the owner reaching between
    # the yielding mesh's vertices, a rim the moved faces still cross) the owner gives up
    # there, onto the closest yielded surface: these are shallow, and a way out towards
    # the owner's centre can run far along a flat owner (a plate's floor under a fruit)
    for owner, loser in decided:
        now = trimesh.Trimesh(out[loser], faces[loser], process=False)
        hit = _inside(_Surface(now), out[owner])
        limit_m = MAX_DENT_FRACTION * surfaces[owner].thickness_m
        if hit is not None and float(hit[1].max()) <= limit_m:
            give(owner, loser, hit, None)
    new = {i: out[i] for i in ids if moved[i].any()}
    reports = {i: YieldReport(int(moved[i].sum()), deepest[i], tuple(owners[i])) for i in new}
    return new, reports, overlap_m


def _inside(surface: _Surface, verts: np.ndarray):
    """The vertices (V, 3) that lie inside the surface's mesh by ``MIN_DEPTH_M`` to
    ``MAX_DEPTH_M``: (indices (K,), depth (K,) m, closest surface points (K, 3), outward
    normals there (K, 3)); None for none. Inside by ray parity for a closed mesh; for an open one (a
    single-image model often has small holes and flipped faces) behind the closest face
    within ``NEAR_FACE_M`` of it, and farther by the winding number of the mesh decimated
    to ``WINDING_FACES`` faces (a flipped face can face a point deep inside)."""
    box = np.asarray(surface.mesh.bounds)
    near = np.flatnonzero(np.all((verts >= box[0]) & (verts <= box[1]), axis=1))
    if not len(near):
        return None
    closest, normal = closest_surface_points(surface.scene, verts[near])
    offset = verts[near] - closest
    depth = np.linalg.norm(offset, axis=1)
    keep = np.flatnonzero((depth > MIN_DEPTH_M) & (depth < MAX_DEPTH_M))
    if not len(keep):
        return None
    pts = verts[near[keep]]
    if surface.closed:
        inside = occupancy(surface.scene, pts)
    else:
        inside = np.einsum("ni,ni->n", offset[keep], normal[keep]) < 0.0
        far = depth[keep] >= NEAR_FACE_M
        if far.any():
            v, f = surface.decimated
            inside[far] = winding_number(v, f, pts[far]) > 0.5
    keep = keep[inside]
    if not len(keep):
        return None
    return near[keep], depth[keep], closest[keep], normal[keep]


def _way_out(owner: _Surface, points: np.ndarray, centre: np.ndarray,
             closest: np.ndarray, normal: np.ndarray, clearance_m: float) -> np.ndarray:
    """New positions (K, 3) of the yielding points (K, 3), which lie inside ``owner``.

    The closest surface point (``closest``, outward ``normal``: (K, 3)) plus the clearance,
    where that surface faces the yielding object's centre (3,): neighbouring vertices go
    to neighbouring surface points, so the dent is as smooth as the owner. Where the
    closest surface faces away from it (a fruit sunk into the thin floor of a plate: the
    floor's underside is nearest) the point goes instead to where the ray from it towards
    the centre leaves the owner, plus the clearance (the floor's top), unless that exit is
    farther than ``MAX_DEPTH_M``."""
    towards = centre[None, :] - points
    out = closest + clearance_m * normal
    wrong_side = np.einsum("ni,ni->n", normal, towards) < 0.0
    if not wrong_side.any():
        return out
    direction = towards[wrong_side]
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)
    t = first_hit_distance(owner.scene, points[wrong_side], direction)
    ok = np.isfinite(t) & (t < MAX_DEPTH_M)
    idx = np.flatnonzero(wrong_side)[ok]
    out[idx] = points[idx] + (t[ok] + clearance_m)[:, None] * direction[ok]
    return out


def lift_onto_plane(vertices: np.ndarray, plane_point: np.ndarray, plane_normal: np.ndarray,
                    clearance_m: float = CLEARANCE_M, max_depth_m: float = MAX_LIFT_M
                    ) -> tuple[np.ndarray, int]:
    """Vertices (V, 3) world with every one below the support plane (more than
    ``MIN_DEPTH_M``) moved up along its normal onto it, plus the clearance; and how many
    moved. Below the table is never seen: a prior reaching a few millimetres there is a
    shape error in hidden space, and moving the whole object up would move what the camera
    saw. A prior deeper than ``max_depth_m`` is left as it is (none moved): that is a pose
    error, for geomopt to lift the whole object."""
    v = np.asarray(vertices, dtype=np.float64)
    h = _heights_m(v, plane_point, plane_normal)
    if len(h) and float(h.min()) < -max_depth_m:
        return v.copy(), 0
    n = np.asarray(plane_normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    below = h < -MIN_DEPTH_M
    out = v.copy()
    out[below] += (clearance_m - h[below])[:, None] * n
    return out, int(below.sum())


def sunk_too_far(vertices: np.ndarray, plane_point: np.ndarray, plane_normal: np.ndarray,
                 max_depth_m: float = MAX_LIFT_M) -> bool:
    """Whether a posed prior (vertices (V, 3) world) reaches more than ``max_depth_m`` below
    the support plane: it was registered too low, a pose error. Its overlaps with the
    others come from that error, not from its hidden shape, so it takes no part in
    :func:`yield_hidden_overlaps` (geomopt moves it instead)."""
    h = _heights_m(np.asarray(vertices, dtype=np.float64), plane_point, plane_normal)
    return bool(len(h) and float(h.min()) < -max_depth_m)


def _heights_m(vertices: np.ndarray, plane_point: np.ndarray, plane_normal: np.ndarray
               ) -> np.ndarray:
    n = np.asarray(plane_normal, dtype=np.float64)
    return (vertices - np.asarray(plane_point, dtype=np.float64)) @ (n / np.linalg.norm(n))


def _first_owns(lens: np.ndarray, first: cKDTree | None, second: cKDTree | None) -> bool:
    """Whether the overlap (its vertices, (M, 3)) belongs to the first shape: its observed
    points are at least as near (median distance). A shape without points owns nothing,
    unless neither has points: then the first (lower id) owns."""
    if first is None or second is None:
        return second is None
    return bool(np.median(first.query(lens)[0]) <= np.median(second.query(lens)[0]))


def _boxes_meet(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.all(a[0] <= b[1]) and np.all(b[0] <= a[1]))
