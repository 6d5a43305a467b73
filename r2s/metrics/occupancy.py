"""Inside/outside tests of points against a triangle mesh by ray-crossing parity.

Rays are cast from each point along +x, +y and +z; a point is inside when an odd number
of triangles is crossed along at least two of the three axes (the vote makes small holes
or a ray grazing an edge cost nothing). Triangles are binned into a 2-D grid on the plane
across each axis, so each point is tested only against the triangles of its cell: a few
tens of milliseconds for 10^4 points and 10^4 faces (trimesh's generic ray ``contains``
without embree takes tens of seconds for the same).

Exact for closed (watertight) meshes up to measure-zero ties; an approximation otherwise.
"""

from __future__ import annotations

import numpy as np
import trimesh

_CHUNK_POINTS = 20000


def _expand_ranges(starts: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For ranges ``[starts[k], starts[k] + counts[k])``: (owner k, value) of every element."""
    owner = np.repeat(np.arange(len(counts)), counts)
    first = np.cumsum(counts) - counts
    values = starts[owner] + (np.arange(int(counts.sum())) - first[owner])
    return owner, values


def crossing_counts(triangles: np.ndarray, points: np.ndarray, axis: int) -> np.ndarray:
    """Number of triangles crossed by the ray from each point along ``+axis``.

    Parameters
    ----------
    triangles : (F, 3, 3) float vertices.
    points : (M, 3) float.
    axis : 0, 1 or 2.

    Returns
    -------
    (M,) int.
    """
    u, v = [k for k in range(3) if k != axis]
    tri_uv = triangles[:, :, [u, v]]                           # (F, 3, 2)
    pts_uv = points[:, [u, v]]
    lo = np.minimum(tri_uv.reshape(-1, 2).min(axis=0), pts_uv.min(axis=0))
    hi = np.maximum(tri_uv.reshape(-1, 2).max(axis=0), pts_uv.max(axis=0))
    n_cells = int(np.clip(np.sqrt(len(triangles)), 8, 256))
    cell = np.maximum(hi - lo, 1e-12) / n_cells

    def cell_of(uv: np.ndarray) -> np.ndarray:
        return np.clip(((uv - lo) / cell).astype(np.int64), 0, n_cells - 1)

    # bin triangles by the cells their (u, v) bounding box covers
    c0, c1 = cell_of(tri_uv.min(axis=1)), cell_of(tri_uv.max(axis=1))
    span = c1 - c0 + 1                                           # (F, 2)
    tri_owner, flat = _expand_ranges(np.zeros(len(triangles), np.int64), span[:, 0] * span[:, 1])
    ci = c0[tri_owner, 0] + flat // span[tri_owner, 1]
    cj = c0[tri_owner, 1] + flat % span[tri_owner, 1]
    cell_ids = ci * n_cells + cj
    order = np.argsort(cell_ids, kind="stable")
    cell_sorted, tri_sorted = cell_ids[order], tri_owner[order]

    counts = np.zeros(len(points), dtype=np.int64)
    for s in range(0, len(points), _CHUNK_POINTS):
        p = points[s:s + _CHUNK_POINTS]
        pc = cell_of(p[:, [u, v]])
        pcell = pc[:, 0] * n_cells + pc[:, 1]
        begin = np.searchsorted(cell_sorted, pcell, side="left")
        end = np.searchsorted(cell_sorted, pcell, side="right")
        owner, idx = _expand_ranges(begin, end - begin)
        t = triangles[tri_sorted[idx]]                           # (P, 3, 3)
        q = p[owner]
        a, b, c = t[:, 0], t[:, 1], t[:, 2]
        qu, qv = q[:, u], q[:, v]
        w0 = (c[:, u] - b[:, u]) * (qv - b[:, v]) - (c[:, v] - b[:, v]) * (qu - b[:, u])
        w1 = (a[:, u] - c[:, u]) * (qv - c[:, v]) - (a[:, v] - c[:, v]) * (qu - c[:, u])
        w2 = (b[:, u] - a[:, u]) * (qv - a[:, v]) - (b[:, v] - a[:, v]) * (qu - a[:, u])
        area = w0 + w1 + w2
        inside = (((w0 >= 0) & (w1 >= 0) & (w2 >= 0)) | ((w0 <= 0) & (w1 <= 0) & (w2 <= 0)))
        inside &= np.abs(area) > 1e-20
        safe = np.where(np.abs(area) > 1e-20, area, 1.0)
        hit_coord = (w0 * a[:, axis] + w1 * b[:, axis] + w2 * c[:, axis]) / safe
        hit = inside & (hit_coord > q[:, axis])
        counts[s:s + len(p)] = np.bincount(owner[hit], minlength=len(p))
    return counts


def contains(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """(M,) bool: which of ``points`` (M, 3) lie inside ``mesh`` (same frame)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros(0, dtype=bool)
    triangles = np.asarray(mesh.triangles, dtype=np.float64)
    votes = sum((crossing_counts(triangles, points, axis) % 2).astype(np.int64)
                for axis in range(3))
    return votes >= 2
