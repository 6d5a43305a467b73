"""Convex collision pieces cut where two objects' pieces overlap as Bullet measures it.

:mod:`r2s.geometry.collision_trim` rebuilds a piece where a neighbour's *visual* surface
lies inside it. Two pieces can still overlap where neither visual surface reaches far into
the other piece: each piece overshoots its own mesh a little on the side facing the other
(a plate's piece spans a few mm of air over its curved floor, a fruit's piece cuts across
a dent of its underside), the two overshoots add up, and Bullet separates the two bodies by
the whole overlap along one direction (its penetration depth), so physopt's depenetration
lifts the fruit by that much. Measured on the seed demo without priors (docs/
convex_decomposition.md): piece pairs overlapping by 2.1-7.4 mm where the visual meshes
reach at most 0.7 mm into each other.

Here every pair of pieces of two different objects is measured in a PyBullet world with
the pieces as static bodies at the objects' poses (:func:`piece_overlaps`), and of each
pair that overlaps by more than a tolerance the piece of the object resting on the other
is cut by a plane across Bullet's penetration direction (:func:`shave_overlaps`). All
poses are (4, 4) ``world_from_object``; pieces are in their object's frame; metres.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet as pb
import trimesh

from r2s.geometry.camera import transform_points
from r2s.geometry.collision_trim import capped_hull, inside_depth_m
from r2s.geometry.sdf import raycasting_scene, winding_number
from r2s.physopt.pybullet_world import BULLET_MARGIN_M, obj_file_bytes
from r2s.sim.pybullet_bodies import connect_direct, quat_xyzw_from_matrix

PieceKey = tuple[int, int]
"""(object id, index of the piece in that object's list)."""

OVERLAP_TOLERANCE_M = 1.5e-3
"""Overlaps deeper than this, as Bullet reports them (its margins included), are what
physopt's depenetration pushes apart (its tolerance, r2s.physopt.pybullet_world)."""


@dataclass(frozen=True)
class Overlap:
    """Two pieces of different objects that Bullet finds overlapping by ``depth_m``."""

    a: PieceKey
    b: PieceKey
    depth_m: float
    normal_world: np.ndarray  # (3,) Bullet's contact normal on b, pointing towards a


def piece_overlaps(pieces: dict[int, list[trimesh.Trimesh]], poses: dict[int, np.ndarray],
                   min_depth_m: float = OVERLAP_TOLERANCE_M) -> list[Overlap]:
    """Every pair of pieces of two different objects that overlaps by more than
    ``min_depth_m`` as Bullet measures it (its depth includes its collision margin),
    deepest first.

    Bullet inflates every convex piece by :data:`BULLET_MARGIN_M`, so it reports two
    pieces as overlapping by their geometric overlap plus twice that (touching hulls: 2
    mm). The bounding boxes that pick the pairs to measure are geometric, so they are
    compared with the same allowance: a pair whose boxes overlap by only 1 mm along one
    axis can read 3 mm (measured on a cup lying against a drill: 2.88 mm, boxes 0.88 mm
    along one axis; a box test at ``min_depth_m`` skipped the pair, docs/
    convex_decomposition.md)."""
    client = connect_direct()
    tmp = tempfile.TemporaryDirectory(prefix="r2s-overlap-")
    try:
        bodies = _static_pieces(client, Path(tmp.name), pieces, poses)
        boxes = {k: _world_box(p, poses[k[0]]) for k, p in _items(pieces)}
        keys = sorted(bodies)
        out = []
        for n, ka in enumerate(keys):
            for kb in keys[n + 1:]:
                if ka[0] == kb[0] or not _boxes_meet(boxes[ka], boxes[kb],
                                                     min_depth_m - 2 * BULLET_MARGIN_M):
                    continue
                pts = pb.getClosestPoints(bodies[ka], bodies[kb], 0.0, physicsClientId=client)
                if not pts:
                    continue
                deepest = min(pts, key=lambda p: p[8])
                if -deepest[8] > min_depth_m:
                    out.append(Overlap(ka, kb, -float(deepest[8]),
                                       np.asarray(deepest[7], dtype=float)))
        return sorted(out, key=lambda o: -o.depth_m)
    finally:
        pb.disconnect(client)
        tmp.cleanup()


def _items(pieces: dict[int, list[trimesh.Trimesh]]):
    return (((i, k), p) for i in sorted(pieces) for k, p in enumerate(pieces[i]))


def _static_pieces(client: int, folder: Path, pieces: dict[int, list[trimesh.Trimesh]],
                   poses: dict[int, np.ndarray]) -> dict[PieceKey, int]:
    """Each piece as a static PyBullet body at its object's pose."""
    bodies = {}
    for key, piece in _items(pieces):
        path = folder / f"{key[0]}_{key[1]}.obj"
        path.write_bytes(obj_file_bytes(piece))  # remembered: the rounds rebuild worlds
        shape = pb.createCollisionShape(pb.GEOM_MESH, fileName=str(path),
                                        physicsClientId=client)
        pose = np.asarray(poses[key[0]], dtype=float)
        bodies[key] = pb.createMultiBody(0.0, shape, basePosition=pose[:3, 3].tolist(),
                                         baseOrientation=quat_xyzw_from_matrix(pose[:3, :3]),
                                         physicsClientId=client)
    return bodies


def _world_box(piece: trimesh.Trimesh, pose: np.ndarray) -> np.ndarray:
    corners = transform_points(np.asarray(pose), trimesh.bounds.corners(piece.bounds))
    return np.array([corners.min(axis=0), corners.max(axis=0)])


def _boxes_meet(a: np.ndarray, b: np.ndarray, depth_m: float) -> bool:
    return bool(np.all(a[0] < b[1] - depth_m) and np.all(b[0] < a[1] - depth_m))


@dataclass(frozen=True)
class OverlapShave:
    """What :func:`shave_overlaps` did to one object: its deepest overlap with the pieces
    of the objects before it in the order, before and after (m, as Bullet reports it),
    and how many cuts were made in its pieces."""

    depth_before_m: float
    depth_after_m: float
    cuts: int


def shave_overlaps(pieces: dict[int, list[trimesh.Trimesh]],
                   meshes: dict[int, trimesh.Trimesh], poses: dict[int, np.ndarray],
                   order: list[int], support: tuple[np.ndarray, np.ndarray] | None = None,
                   rounds: int = 5, min_depth_m: float = OVERLAP_TOLERANCE_M
                   ) -> tuple[dict[int, list[trimesh.Trimesh]], dict[int, OverlapShave]]:
    """Of two overlapping pieces of different objects, the piece of the object later in
    ``order`` (root to leaves: the one resting on the other) is cut by the plane that
    separates it from the other along Bullet's penetration direction (at the other piece's
    extent along it), repeated up to ``rounds`` times.

    The later object's collision surface then ends at the earlier one's piece where they
    overlap (a fruit's underside at the plate's piece: a few mm above its visual surface),
    so it rests where it was seen instead of being pushed off by the whole overlap. A cut
    only removes: every piece stays inside its uncut self. A piece cut away entirely is
    dropped, unless it is its object's last. ``support`` (a point and the upward unit
    normal of the table plane, world) first cuts every piece that reaches more than
    :data:`BELOW_SUPPORT_M` below the table at the table (or at the object's visual mesh
    where that is lower).

    Only the pieces' overshoot is cut: where two objects' visual ``meshes`` themselves
    interpenetrate by more than :data:`VISUAL_PENETRATION_M`, their pieces are left for
    the depenetration to push apart (a mesh sunk into the table is lifted the same way).
    Returns the pieces and a report per object whose pieces were cut."""
    rank = {i: k for k, i in enumerate(order)}
    out = {i: list(p) for i, p in pieces.items()}
    if support is not None:
        out = {i: _without_empty([_below_cut(p, poses[i], meshes[i], *support) for p in ps],
                                 ps) for i, ps in out.items()}
    sunk: dict[tuple[int, int], bool] = {}
    overlaps = piece_overlaps(out, poses, min_depth_m)
    before = _deepest_by_object(overlaps)
    cut: dict[int, int] = {}
    for _ in range(rounds):
        if not overlaps:
            break
        done: set[PieceKey] = set()
        for o in overlaps:
            swap = rank.get(o.a[0], 0) > rank.get(o.b[0], 0)
            later, earlier = (o.a, o.b) if swap else (o.b, o.a)
            if later in done or earlier in done:
                continue  # measured before one of them was cut: the next round measures again
            pair = (min(later[0], earlier[0]), max(later[0], earlier[0]))
            if pair not in sunk:
                sunk[pair] = visual_penetration_m(meshes, poses, *pair) > VISUAL_PENETRATION_M
            if sunk[pair]:
                continue
            # Bullet's normal points from b to a; `away` from the earlier piece to the later
            away = _unit(o.normal_world if swap else -o.normal_world)
            piece = out[later[0]][later[1]]
            out[later[0]][later[1]] = _cut_piece(piece, poses[later[0]],
                                                 out[earlier[0]][earlier[1]],
                                                 poses[earlier[0]], away, support)
            done.add(later)
            if out[later[0]][later[1]] is not piece:
                cut[later[0]] = cut.get(later[0], 0) + 1
        out = {i: _without_empty(p, pieces[i]) for i, p in out.items()}
        overlaps = piece_overlaps(out, poses, min_depth_m)
    after = _deepest_by_object(overlaps)
    return out, {i: OverlapShave(before.get(i, 0.0), after.get(i, 0.0), n)
                 for i, n in sorted(cut.items())}


CUT_CLEARANCE_M = 1.0e-3
"""A cut leaves this much between the two pieces' hulls: Bullet reports two convex hulls
that touch as overlapping by about 2 mm (its margins), and physopt's depenetration leaves
bodies at 1 mm (r2s.physopt.pybullet_world.BULLET_MARGIN_M); cut 1 mm further, a cut pair
reports about 1 mm and is not pushed apart."""

TABLE_CONTACT_M = 1.0e-3
"""A piece's vertices this close to the table plane are where it stands on the table."""

BELOW_SUPPORT_M = 0.5e-3
"""A piece reaching further below the table plane than this is cut at the plane."""


VISUAL_PENETRATION_M = 5.0e-3
"""Visual meshes interpenetrating deeper than this are a real overlap, not the pieces'
overshoot: geomopt keeps init's poses where their overlaps are at most 3 mm
(r2s.geomopt.optimise.SMALL_PENETRATION_M), so an overlap it accepts is cut here, not
pushed apart by the pieces' larger overlap. geomopt reads an overlap from its SDF grids at
surface samples, which reads less than the exact distance used here: on the tenth fresh
set's scene_01 it accepted a pair it read at 2.0 mm at most that reads 3.5 mm here, and
the push moved the object 15.9 mm (docs/realistic.md, "A visual overlap a little over
3 mm"). Hence 5 mm. History: 1.5 mm before 2026-11-29 (on the realistic scene_05 a 1.6 mm
visual overlap of two clamps let depenetration push one 10.9 mm; docs/completion.md), 3 mm
until 2026-12-07."""

VISUAL_SAMPLES = 3000
"""Surface samples of a mesh for the visual penetration test."""


def visual_penetration_m(meshes: dict[int, trimesh.Trimesh], poses: dict[int, np.ndarray],
                          i: int, j: int) -> float:
    """How deep the visual meshes of objects i and j reach into each other (m): the
    deepest surface sample of one behind the nearest face of the other (the side its
    normal gives, so meshes with holes count too)."""
    deepest = 0.0
    for a, b in ((i, j), (j, i)):
        samples, _ = trimesh.sample.sample_surface(meshes[b], VISUAL_SAMPLES, seed=5)
        local = transform_points(np.linalg.inv(poses[a]) @ np.asarray(poses[b]), samples)
        lo, hi = meshes[a].bounds
        local = local[np.all((local > lo) & (local < hi), axis=1)]
        if len(local):
            deepest = max(deepest, float(np.max(_behind_surface_m(meshes[a], local))))
    return deepest


def _behind_surface_m(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """(N,) how deep each point lies inside ``mesh`` (m; 0 outside): its distance to the
    nearest face where it lies behind that face; a point deeper than
    VISUAL_PENETRATION_M is confirmed by the winding number (a completed plate is not
    closed and a face's normal alone can point the wrong way)."""
    import open3d as o3d  # heavy import, only where needed

    scene = raycasting_scene(mesh.vertices, mesh.faces)
    found = scene.compute_closest_points(
        o3d.core.Tensor(np.ascontiguousarray(points, dtype=np.float32)))
    offset = points - found["points"].numpy()
    distance = np.linalg.norm(offset, axis=1)
    behind = np.einsum("ij,ij->i", offset, found["primitive_normals"].numpy()) < 0
    deep = np.flatnonzero(behind & (distance > VISUAL_PENETRATION_M))
    if len(deep):
        inside = winding_number(mesh.vertices, mesh.faces, points[deep], chunk=64) > 0.5
        behind[deep[~inside]] = False
    return np.where(behind, distance, 0.0)


def _below_cut(piece: trimesh.Trimesh, pose: np.ndarray, mesh: trimesh.Trimesh,
               point: np.ndarray, normal: np.ndarray) -> trimesh.Trimesh | None:
    """``piece`` (object frame at ``pose``) cut at the table plane through ``point`` with
    upward unit ``normal`` (world), or at the lowest point of the visual ``mesh`` where that
    is lower, when it reaches below that by more than BELOW_SUPPORT_M."""
    up = _unit(normal)
    visual = float(np.min((transform_points(pose, np.asarray(mesh.vertices)) - point) @ up))
    heights = (transform_points(pose, np.asarray(piece.vertices)) - np.asarray(point)) @ up
    heights = heights - min(visual, 0.0)
    if heights.min() >= -BELOW_SUPPORT_M:
        return piece
    return _clipped(piece, heights)


def _unit(v: np.ndarray) -> np.ndarray:
    return np.asarray(v, dtype=float) / max(float(np.linalg.norm(v)), 1e-12)


def _cut_piece(piece: trimesh.Trimesh, pose: np.ndarray, other: trimesh.Trimesh,
               other_pose: np.ndarray, away_world: np.ndarray,
               support: tuple[np.ndarray, np.ndarray] | None = None) -> trimesh.Trimesh | None:
    """``piece`` (object frame at ``pose``) less the half-space behind ``other``'s extent
    along ``away_world`` (unit, world); None when nothing is left. The piece is returned
    uncut when a cut from below would take away where it stands on the table
    (``support``: point, upward unit normal): a piece that overlaps its neighbour's while
    resting on the table is beside the neighbour, and cutting its foot would drop it."""
    level = float(np.max(transform_points(other_pose, np.asarray(other.vertices)) @ away_world)
                  ) + CUT_CLEARANCE_M
    normal = np.asarray(pose)[:3, :3].T @ away_world
    origin = transform_points(np.linalg.inv(pose), (level * away_world)[None])[0]
    heights = np.asarray(piece.vertices) @ normal - origin @ normal
    if heights.min() >= 0.0:
        return piece
    if support is not None and float(away_world @ _unit(support[1])) > 0.5:
        world = transform_points(pose, np.asarray(piece.vertices))
        on_table = (world - support[0]) @ _unit(support[1]) < TABLE_CONTACT_M
        if np.any(on_table & (heights < 0.0)):
            return piece
    return _clipped(piece, heights)


def _clipped(piece: trimesh.Trimesh, heights: np.ndarray) -> trimesh.Trimesh | None:
    """The convex ``piece`` clipped to ``heights >= 0`` ((V,) signed distances of its
    vertices to the cutting plane), or None when (almost) nothing is left."""
    if heights.max() <= 1e-4:
        return None
    return capped_hull(_clipped_vertices(piece, heights))


def _clipped_vertices(piece: trimesh.Trimesh, heights: np.ndarray) -> np.ndarray:
    """(K, 3) corners of a convex piece clipped to ``heights >= 0`` (heights: (V,) signed
    distances of its vertices to the cutting plane): the vertices kept and the points where
    its edges cross the plane."""
    return np.vstack([np.asarray(piece.vertices)[heights >= 0], plane_crossings(piece, heights)])


def plane_crossings(piece: trimesh.Trimesh, heights: np.ndarray) -> np.ndarray:
    """(K, 3) points where the piece's edges cross a plane (``heights``: (V,) signed
    distances of its vertices to it), in the piece's frame."""
    vertices = np.asarray(piece.vertices)
    edges = np.asarray(piece.edges_unique)
    ha, hb = heights[edges[:, 0]], heights[edges[:, 1]]
    crossing = (ha < 0) != (hb < 0)
    t = ha[crossing] / (ha[crossing] - hb[crossing])
    a, b = vertices[edges[crossing, 0]], vertices[edges[crossing, 1]]
    return a + t[:, None] * (b - a)


def _without_empty(cut: list, uncut: list[trimesh.Trimesh]) -> list[trimesh.Trimesh]:
    """The pieces left; an object whose every piece was cut away keeps its first piece."""
    kept = [p for p in cut if p is not None]
    return kept or [uncut[0]]


def _deepest_by_object(overlaps: list[Overlap]) -> dict[int, float]:
    out: dict[int, float] = {}
    for o in overlaps:
        for key in (o.a, o.b):
            out[key[0]] = max(out.get(key[0], 0.0), o.depth_m)
    return out
