"""Convex collision pieces trimmed where a neighbour's visual mesh reaches into them.

A convex piece of a concave mesh spans part of the concavity (and V-HACD's voxel hulls
overshoot the surface a little): a neighbour resting close to, but not touching, the visual
mesh then sits inside the piece, and the judge's depenetration pushes it away by that much.
Here every piece that a neighbour's surface reaches into by more than a tolerance is
rebuilt from the object's own geometry inside it (its surface samples, and the piece's own
points that lie inside the mesh): first as one hull of those points (removes the
overshoot), then, while a neighbour still reaches in, split in two by a plane through the
intruding points and hulled again on each side (opens a spanned concavity), a few levels
deep. Pieces no neighbour reaches into are kept as they are.

Every piece is a hull of points of the object itself, so no piece grows; the object's
surface stays covered up to the spacing of its samples and the 64-vertex cap of a rebuilt
piece (at most 1.06 mm outside on the realistic benchmark objects, docs/
convex_decomposition.md). Deterministic: the samples are drawn with fixed seeds. All
arrays are metres in the object frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError

from r2s.forked_map import forked_map
from r2s.geometry.camera import transform_points
from r2s.geometry.sdf import occupancy, raycasting_scene

TRIM_TOLERANCE_M = 1e-3
"""Neighbour points inside a piece by at most this much are left alone (Bullet's margin)."""

SURFACE_SAMPLES = 10_000
"""Surface samples of the object itself (about 2 mm apart on a 15 cm object)."""

NEIGHBOUR_SAMPLES = 4_000
"""Surface samples of each neighbour."""

MAX_SPLIT_DEPTH = 3
"""A trimmed piece becomes at most 2**MAX_SPLIT_DEPTH pieces."""

MAX_HULL_VERTICES = 64
"""Most vertices of a rebuilt piece (V-HACD's bound here too: Bullet's cost grows with it)."""

SPLIT_OVERLAP_M = 1.5e-3
"""Own points this close to a split plane go to both sides (no seam in the cover)."""


@dataclass(frozen=True)
class TrimReport:
    """What :func:`trim_pieces` did: intrusion depth (m) of the neighbours' surfaces into
    the pieces before and after, and the piece counts."""

    depth_before_m: float
    depth_after_m: float
    pieces_before: int
    pieces_after: int


def inside_depth_m(piece: trimesh.Trimesh, points: np.ndarray, slack_m: float = 0.0
                   ) -> np.ndarray:
    """(N,) how deep each point lies inside a convex piece (m; negative outside, -inf
    farther than ``slack_m`` outside its bounding box)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.full(len(points), -np.inf)
    lo, hi = piece.bounds
    near = np.flatnonzero(np.all((points >= lo - slack_m) & (points <= hi + slack_m), axis=1))
    if len(near) == 0:
        return out
    normals = np.asarray(piece.face_normals)
    offsets = np.einsum("ij,ij->i", normals, np.asarray(piece.triangles[:, 0]))
    planes = np.unique(np.round(np.column_stack([normals, -offsets]), 9), axis=0)
    out[near] = _depths(planes, points[near])
    return out


def surface_points(mesh: trimesh.Trimesh, count: int, seed: int = 0) -> np.ndarray:
    """(count + V, 3) deterministic surface samples of ``mesh`` plus its vertices."""
    samples, _ = trimesh.sample.sample_surface(mesh, count, seed=seed)
    return np.vstack([np.asarray(samples), np.asarray(mesh.vertices)])


def _greedy_hull_vertices(corners: np.ndarray, count: int) -> np.ndarray:
    """(count,) indices of the hull ``corners`` (N, 3) whose hull loses the least: start
    from the extremes along x, y, z, then add, one at a time, the corner farthest outside
    the hull of those chosen (deterministic)."""
    chosen = sorted({int(i) for axis in range(3)
                     for i in (np.argmin(corners[:, axis]), np.argmax(corners[:, axis]))})
    while len(chosen) < min(count, len(corners)):
        planes = _hull_planes(corners[chosen])
        if planes is None:  # flat start: add the corner farthest from those chosen
            far = np.min(np.linalg.norm(corners[:, None] - corners[chosen][None], axis=2),
                         axis=1)
            chosen.append(int(np.argmax(far)))
            continue
        outside = -_depths(planes, corners)
        outside[chosen] = -np.inf
        if outside.max() <= 0:
            break
        chosen.append(int(np.argmax(outside)))
    return np.asarray(chosen)


def capped_hull(points: np.ndarray, max_vertices: int = MAX_HULL_VERTICES
                ) -> trimesh.Trimesh | None:
    """Convex hull of (N, 3) points with at most ``max_vertices`` vertices (of the full
    hull's vertices, those that keep the most of it), or None when degenerate."""
    if len(points) < 4:
        return None
    try:
        hull = trimesh.convex.convex_hull(points)
        if len(hull.vertices) > max_vertices:
            corners = np.asarray(hull.vertices)
            hull = trimesh.convex.convex_hull(
                corners[_greedy_hull_vertices(corners, max_vertices)])
    except (QhullError, ValueError):
        return None
    return hull if hull.volume > 1e-10 else None


def _max_depth(piece: trimesh.Trimesh, points: np.ndarray) -> float:
    return float(inside_depth_m(piece, points).max()) if len(points) else -np.inf


def _split_candidates(own: np.ndarray, intruding: np.ndarray) -> list[tuple[np.ndarray, float]]:
    """(normal, offset) planes at the intruding points: along the own points' principal
    axes and along the direction from them to the intruders, through the intruders' median
    and just past either end of them."""
    centre = own.mean(axis=0)
    _, _, axes = np.linalg.svd(own - centre, full_matrices=False)
    directions = list(axes)
    towards = intruding.mean(axis=0) - centre
    if np.linalg.norm(towards) > 1e-9:
        directions.append(towards / np.linalg.norm(towards))
    planes = []
    for n in directions:
        n = n if n[np.argmax(np.abs(n))] > 0 else -n  # a fixed sign: deterministic
        along = intruding @ n
        for offset in (along.min() - SPLIT_OVERLAP_M, np.median(along),
                       along.max() + SPLIT_OVERLAP_M):
            planes.append((n, float(offset)))
    return planes


def _hull_planes(points: np.ndarray) -> np.ndarray | None:
    """(K, 4) facet planes [n, d] of the hull of (N, 3) points (n.x + d <= 0 inside), or
    None when degenerate; cheaper than a mesh, for scoring candidate splits."""
    if len(points) < 4:
        return None
    try:
        return ConvexHull(points).equations
    except (QhullError, ValueError):
        return None


def _intrusion(planes: np.ndarray, intruders: np.ndarray, tol_m: float) -> float:
    """Sum over the intruding points of how far past ``tol_m`` they lie inside the hull
    given by its ``planes`` (m)."""
    return float(np.clip(_depths(planes, intruders) - tol_m, 0.0, None).sum())


def _best_split(own: np.ndarray, inside: np.ndarray, tol_m: float
                ) -> tuple[float, list[np.ndarray]] | None:
    """Of the candidate planes the split of ``own`` that leaves the least summed intrusion
    of ``inside`` (then the least volume): (intrusion, [points of each side])."""
    best = None
    for normal, offset in _split_candidates(own, inside):
        side = own @ normal - offset
        parts = [own[side <= SPLIT_OVERLAP_M], own[side >= -SPLIT_OVERLAP_M]]
        if min(len(p) for p in parts) == len(own):
            continue
        planes = [_hull_planes(p) for p in parts]
        if any(p is None for p in planes):
            continue
        score = round(sum(_intrusion(p, inside, tol_m) for p in planes), 9)
        if best is None or score < best[0]:
            best = (score, parts)
    return best


def _rebuild(own: np.ndarray, intruders: np.ndarray, tol_m: float,
             depth: int, max_depth: int = MAX_SPLIT_DEPTH) -> list[trimesh.Trimesh]:
    """Hulls of ``own`` points, split while ``intruders`` reach into them by > tol_m (by
    :func:`_best_split`, kept only when it lowers the intrusion)."""
    planes = _hull_planes(own)
    if planes is None:
        return []
    inside = intruders[_depths(planes, intruders) > tol_m] if len(intruders) else intruders
    if len(inside) and depth < max_depth:
        best = _best_split(own, inside, tol_m)
        if best is not None and best[0] < _intrusion(planes, inside, tol_m):
            return [h for part in best[1] for h in _rebuild(part, intruders, tol_m, depth + 1,
                                                                  max_depth)]
    hull = capped_hull(own)
    return [] if hull is None else [hull]


def _depths(planes: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N,) depth of points inside the hull given by its facet ``planes`` (m)."""
    return np.min(-(points @ planes[:, :3].T) - planes[:, 3], axis=1)


def _own_points_of(piece: trimesh.Trimesh, own_surface: np.ndarray, solid) -> np.ndarray:
    """The object's points inside ``piece``: surface samples within it, and the piece's
    vertices and surface samples that lie inside a closed mesh (cut faces of the solid)."""
    on_surface = own_surface[inside_depth_m(piece, own_surface, 0.5e-3) >= -0.5e-3]
    if solid is None:
        return on_surface
    own_cut, _ = trimesh.sample.sample_surface(piece, 600, seed=1)
    candidates = np.vstack([np.asarray(piece.vertices), np.asarray(own_cut)])
    return np.vstack([on_surface, candidates[occupancy(solid, candidates)]])


def trim_pieces(pieces: list[trimesh.Trimesh], mesh: trimesh.Trimesh,
                neighbour_points: np.ndarray, tol_m: float = TRIM_TOLERANCE_M,
                max_split_depth: int = MAX_SPLIT_DEPTH
                ) -> tuple[list[trimesh.Trimesh], TrimReport]:
    """Pieces of ``mesh`` that ``neighbour_points`` (M, 3; other objects' surface samples in
    this object's frame) reach into by at most about ``tol_m`` where the visual mesh allows
    (a rebuilt piece is split at most ``max_split_depth`` levels deep).

    Points inside the closed mesh itself (touching or interpenetrating visual meshes) are
    not trimmed against. Returns the pieces (untouched ones as given, same order, rebuilt
    ones in their place) and a :class:`TrimReport`."""
    pts = np.asarray(neighbour_points, dtype=np.float64).reshape(-1, 3)
    if len(pts):
        depth = np.max([inside_depth_m(p, pts) for p in pieces], axis=0)
        pts = pts[depth > tol_m]
    solid = raycasting_scene(mesh.vertices, mesh.faces) if mesh.is_watertight else None
    if len(pts) and solid is not None:
        pts = pts[~occupancy(solid, pts)]
    piece_depths = [_max_depth(p, pts) for p in pieces]
    before = max(piece_depths + [0.0])
    if before <= tol_m:
        return list(pieces), TrimReport(before, before, len(pieces), len(pieces))
    own_surface = surface_points(mesh, SURFACE_SAMPLES)
    out: list[trimesh.Trimesh] = []
    for piece, piece_depth in zip(pieces, piece_depths):
        if piece_depth <= tol_m:
            out.append(piece)
            continue
        rebuilt = _rebuild(_own_points_of(piece, own_surface, solid), pts, tol_m, 0,
                           max_split_depth)
        out.extend(rebuilt or [piece])
    after = max([_max_depth(p, pts) for p in out] + [0.0])
    return out, TrimReport(before, after, len(pieces), len(out))


def trim_scene_pieces(pieces: dict[int, list[trimesh.Trimesh]],
                      meshes: dict[int, trimesh.Trimesh], poses: dict[int, np.ndarray],
                      tol_m: float = TRIM_TOLERANCE_M, only: set[int] | None = None,
                      max_split_depth: int = MAX_SPLIT_DEPTH
                      ) -> tuple[dict[int, list[trimesh.Trimesh]], dict[int, TrimReport]]:
    """:func:`trim_pieces` for every object (or those in ``only``; the others keep their
    pieces) against all the others' visual meshes.

    pieces, meshes: by object id, object frame; poses: id -> (4, 4) world_from_object."""
    world_samples = {i: transform_points(poses[i], surface_points(m, NEIGHBOUR_SAMPLES, seed=2))
                     for i, m in meshes.items()}
    out, reports = {}, {}
    todo = []
    for i in sorted(pieces):
        others = [world_samples[j] for j in sorted(meshes) if j != i]
        if not others or (only is not None and i not in only):
            out[i] = list(pieces[i])
        else:
            todo.append((i, np.vstack(others)))

    def trim_one(item: tuple[int, np.ndarray]) -> tuple[list[trimesh.Trimesh], TrimReport]:
        i, others_world = item
        local = transform_points(np.linalg.inv(np.asarray(poses[i])), others_world)
        return trim_pieces(pieces[i], meshes[i], local, tol_m, max_split_depth)

    # each object against the others' visual meshes, independent: side by side on the cores
    for (i, _), (trimmed, report) in zip(todo, forked_map(trim_one, todo)):
        out[i], reports[i] = trimmed, report
    return {i: out[i] for i in sorted(out)}, reports
