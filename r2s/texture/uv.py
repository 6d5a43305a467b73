"""A UV atlas for a mesh that has none: axis-projected charts, split until none overlaps itself.

Open3D's UVAtlas takes about 20 s on a 14k-face mesh on this machine, so r2s makes its own
simple atlas:

1. each face is labelled with the one of the six axis directions (+-x, +-y, +-z) closest to
   its normal, labels are smoothed by a majority vote of edge neighbours (so that a noisy
   surface does not shatter into tiny charts), and charts are the edge-connected groups of
   faces with one label;
2. a chart is projected orthographically along its axis (before smoothing every face is at
   most ~55 degrees off its axis; a relabelled face at most ~78 degrees);
3. a chart whose projection folds over itself (a concave part seen twice along the axis)
   is bisected along its longer side until at most 1 % of its sample points (four per face)
   are covered twice;
4. the charts are shelf-packed, at one common scale (texels per metre), into a square
   texture with a gutter of empty texels around each chart.

A very noisy surface can still give more charts than the texture holds; then the gutter
shrinks to one texel, then overlapping charts are kept whole, then the gutter goes.

UV convention (trimesh's, and what GLB export writes after flipping v): ``u`` grows with
the texture's column, ``v`` grows upwards, so texel ``(row, col)`` of a (S, S) texture has
its centre at ``u = (col + 0.5) / S``, ``v = 1 - (row + 0.5) / S``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

AXES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
                dtype=np.float64)
"""The six projection directions, indexed by a face's label."""

PLANE_AXES = ((1, 2), (1, 2), (0, 2), (0, 2), (0, 1), (0, 1))
"""For each label, the two coordinates kept by its orthographic projection."""

NORMAL_SMOOTHING_PASSES = 3
"""Passes of neighbour averaging of face normals before labelling (noise robustness)."""

MAX_OVERLAP_FRACTION = 0.01
"""A chart is split only when more than this fraction of its sample points is covered
twice: tiny folds of a noisy surface share a few texels rather than shattering the chart."""

SAMPLE_BARY = np.array([[1 / 3, 1 / 3, 1 / 3], [0.6, 0.2, 0.2], [0.2, 0.6, 0.2],
                        [0.2, 0.2, 0.6]])
"""Points strictly inside a face used to test a chart for overlaps."""


@dataclass(frozen=True)
class UVAtlas:
    """A mesh with per-vertex UVs (vertices split along chart seams).

    Attributes
    ----------
    vertices : (V', 3) float64 positions, same frame as the source mesh.
    faces : (F, 3) int64 indices into ``vertices``; face ``k`` is the source's face ``k``.
    uv : (V', 2) float64 texture coordinates in [0, 1] (see the module docstring).
    source_vertex : (V',) int64 index of the source vertex each vertex copies.
    chart : (F,) int64 chart id of every face.
    """

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    source_vertex: np.ndarray
    chart: np.ndarray

    @property
    def chart_count(self) -> int:
        return int(self.chart.max()) + 1 if len(self.chart) else 0


def _welded_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces re-indexed so that vertices at the same position share one index."""
    scale = max(float(np.ptp(vertices, axis=0).max()), 1e-12)
    key = np.round(vertices / (scale * 1e-9)).astype(np.int64)
    _, inverse = np.unique(key, axis=0, return_inverse=True)
    return inverse.reshape(-1)[faces]


def _edge_adjacency(faces: np.ndarray) -> np.ndarray:
    """(E, 2) pairs of faces that share an edge (welded indices)."""
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    owner = np.repeat(np.arange(len(faces)), 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    edges, owner = edges[order], owner[order]
    same = np.all(edges[1:] == edges[:-1], axis=1)
    return np.stack([owner[:-1][same], owner[1:][same]], axis=1)


def _components(n: int, pairs: np.ndarray, members: np.ndarray) -> np.ndarray:
    """Connected-component label (0..C-1) of each of ``members`` under ``pairs``."""
    index = np.full(n, -1, np.int64)
    index[members] = np.arange(len(members))
    keep = (index[pairs[:, 0]] >= 0) & (index[pairs[:, 1]] >= 0)
    a, b = index[pairs[keep, 0]], index[pairs[keep, 1]]
    graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(len(members), len(members)))
    return connected_components(graph, directed=False)[1].astype(np.int64)


def _overlapping(tri2d: np.ndarray, groups: list[np.ndarray], max_overlap: float) -> list[bool]:
    """Whether each group of projected faces covers more than a sliver twice.

    ``tri2d`` is (F, 3, 2); each group's faces are laid side by side along x, each face at
    its own height so that coincident triangles still count as two hits.
    """
    if not groups:
        return []
    soup, rays, owner = [], [], []
    x_offset = 0.0
    for g, faces in enumerate(groups):
        tri = tri2d[faces].copy()
        lo = tri.reshape(-1, 2).min(axis=0)
        width = float(np.ptp(tri.reshape(-1, 2)[:, 0])) if len(faces) else 0.0
        tri -= lo
        tri[..., 0] += x_offset
        z = np.arange(len(faces), dtype=np.float64)[:, None, None] * 1e-3
        soup.append(np.concatenate([tri, np.broadcast_to(z, tri.shape[:2] + (1,))], axis=-1))
        pts = np.einsum("sk,fkd->fsd", SAMPLE_BARY, tri).reshape(-1, 2)
        rays.append(np.concatenate([pts, np.full((len(pts), 1), len(faces) * 1e-3 + 1.0),
                                    np.tile([0.0, 0.0, -1.0], (len(pts), 1))], axis=1))
        owner.append(np.full(len(pts), g))
        x_offset += width * 1.5 + 1e-3
    verts = np.concatenate(soup).reshape(-1, 3)
    scene = o3d.t.geometry.RaycastingScene()
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(verts.astype(np.float32))
    mesh.triangle.indices = o3d.core.Tensor(np.arange(len(verts), dtype=np.int32).reshape(-1, 3))
    scene.add_triangles(mesh)
    counts = scene.count_intersections(
        o3d.core.Tensor(np.concatenate(rays).astype(np.float32))).numpy()
    owner = np.concatenate(owner)
    twice = np.bincount(owner, weights=(counts > 1).astype(float), minlength=len(groups))
    total = np.bincount(owner, minlength=len(groups))
    return (twice > max_overlap * total).tolist()


def _bisect(tri2d: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split a chart's faces in two at the median centroid along its longer side."""
    centroid = tri2d[faces].mean(axis=1)
    axis = int(np.argmax(np.ptp(centroid, axis=0)))
    order = np.argsort(centroid[:, axis], kind="stable")
    half = len(faces) // 2
    return faces[order[:half]], faces[order[half:]]


def _smooth_labels(label: np.ndarray, normal: np.ndarray, pairs: np.ndarray,
                   passes: int = 4) -> np.ndarray:
    """Majority filter of face labels over edge neighbours (noisy normals give tiny charts).

    A face takes the label held by at least two of its neighbours when its own normal is
    within ~78 degrees of that label's axis (so its projection stays well-formed).
    """
    n = len(label)
    unit = normal / np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-30)
    cos_to_axis = unit @ AXES.T  # (F, 6)
    both = np.concatenate([pairs, pairs[:, ::-1]])
    for _ in range(passes):
        votes = np.zeros((n, len(AXES)), np.int32)
        np.add.at(votes, (both[:, 0], label[both[:, 1]]), 1)
        best = np.argmax(votes, axis=1)
        change = (votes[np.arange(n), best] >= 2) & (best != label)
        change &= cos_to_axis[np.arange(n), best] > 0.2
        if not change.any():
            break
        label = np.where(change, best, label)
    return label


def _charts(vertices: np.ndarray, faces: np.ndarray, max_overlap: float
            ) -> tuple[np.ndarray, np.ndarray]:
    """Chart id (F,) and projected corners (F, 3, 2) of every face."""
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    pairs = _edge_adjacency(_welded_faces(vertices, faces))
    smooth = normal.copy()
    for _ in range(NORMAL_SMOOTHING_PASSES):
        acc = smooth.copy()
        np.add.at(acc, pairs[:, 0], smooth[pairs[:, 1]])
        np.add.at(acc, pairs[:, 1], smooth[pairs[:, 0]])
        smooth = acc / np.maximum(np.linalg.norm(acc, axis=1, keepdims=True), 1e-30)
    label = _smooth_labels(np.argmax(smooth @ AXES.T, axis=1), normal, pairs)
    tri2d = np.empty((len(faces), 3, 2))
    for lab, (a, b) in enumerate(PLANE_AXES):
        sel = label == lab
        tri2d[sel] = tri[sel][..., [a, b]]
    pending: list[np.ndarray] = []
    for lab in range(len(AXES)):
        members = np.nonzero(label == lab)[0]
        if len(members) == 0:
            continue
        comp = _components(len(faces), pairs, members)
        order = np.argsort(comp, kind="stable")
        splits = np.cumsum(np.bincount(comp))[:-1]
        pending.extend(np.split(members[order], splits))
    done: list[np.ndarray] = []
    while pending:
        multi = [g for g in pending if len(g) > 1]
        done.extend(g for g in pending if len(g) == 1)
        pending = []
        bad_groups = (_overlapping(tri2d, multi, max_overlap) if max_overlap < 1
                      else [False] * len(multi))
        for group, bad in zip(multi, bad_groups):
            if not bad:
                done.append(group)
                continue
            for half in _bisect(tri2d, group):
                comp = _components(len(faces), pairs, half)
                order = np.argsort(comp, kind="stable")
                pending.extend(np.split(half[order], np.cumsum(np.bincount(comp))[:-1]))
    chart = np.empty(len(faces), np.int64)
    for k, group in enumerate(sorted(done, key=lambda g: int(g.min()))):
        chart[group] = k
    return chart, tri2d


def _shelf_pack(sizes: np.ndarray, side: float) -> np.ndarray | None:
    """Lower-left corners (C, 2) of boxes ``sizes`` (C, 2) in a ``side`` square, or None."""
    order = np.argsort(-sizes[:, 1], kind="stable")
    corners = np.zeros_like(sizes)
    x = y = shelf = 0.0
    for k in order:
        w, h = sizes[k]
        if w > side:
            return None
        if x + w > side:
            x, y, shelf = 0.0, y + shelf, 0.0
        if y + h > side:
            return None
        corners[k] = (x, y)
        x += w
        shelf = max(shelf, h)
    return corners


def _pack(extent_m: np.ndarray, texture_size: int, gutter_px: int
          ) -> tuple[float, np.ndarray] | None:
    """Texels per metre and integer texel corners (C, 2) of every chart's box, or None when
    the charts do not fit even at a vanishing scale."""
    if _shelf_pack(np.full_like(extent_m, 2 * gutter_px + 2), float(texture_size)) is None:
        return None
    usable = texture_size - 2 * gutter_px - 1
    lo, hi = 0.0, usable / max(float(extent_m.max()), 1e-9)
    best = None
    for _ in range(40):
        scale = 0.5 * (lo + hi)
        boxes = np.ceil(extent_m * scale) + 2 * gutter_px + 1
        corners = _shelf_pack(boxes, float(texture_size))
        if corners is None:
            hi = scale
        else:
            lo, best = scale, (scale, corners)
            if hi - lo < 1e-3 * hi:
                break
    return best


def chart_atlas(vertices: np.ndarray, faces: np.ndarray, texture_size: int = 512,
                gutter_px: int = 2) -> UVAtlas:
    """A UV atlas of a triangle mesh (see the module docstring for the method).

    Parameters
    ----------
    vertices : (V, 3) float positions (any frame, metres).
    faces : (F, 3) int.
    texture_size : side of the square texture the atlas is packed for, texels.
    gutter_px : empty texels kept around every chart (bilinear lookups near a chart's border
        then never read another chart).

    Returns
    -------
    :class:`UVAtlas`.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    charts: dict[float, tuple[np.ndarray, np.ndarray]] = {}
    for max_overlap, gutter in ((MAX_OVERLAP_FRACTION, gutter_px), (MAX_OVERLAP_FRACTION, 1),
                                (1.0, 1), (1.0, 0)):
        if gutter > gutter_px:
            continue
        if max_overlap not in charts:
            charts[max_overlap] = _charts(vertices, faces, max_overlap)
        chart, tri2d = charts[max_overlap]
        n_charts = int(chart.max()) + 1
        lo = np.full((n_charts, 2), np.inf)
        hi = np.full((n_charts, 2), -np.inf)
        flat = tri2d.reshape(-1, 2)
        owner = np.repeat(chart, 3)
        np.minimum.at(lo, owner, flat)
        np.maximum.at(hi, owner, flat)
        packed = _pack(hi - lo, texture_size, gutter)
        if packed is not None:
            break
    if packed is None:
        raise ValueError(f"{n_charts} UV charts do not fit a {texture_size}^2 texture")
    scale, corners = packed
    gutter_px = gutter
    # texel coordinates: x = column, y = row (down); corner + gutter + (p - lo) * scale
    texel = corners[owner] + gutter_px + 0.5 + (flat - lo[owner]) * scale
    # one vertex per (chart, source vertex): UV seams split vertices between charts
    wedge_source = faces.reshape(-1)
    key = chart.repeat(3) * (len(vertices) + 1) + wedge_source
    uniq, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    source_vertex = wedge_source[first]
    uv_texel = texel[first]
    uv = np.stack([uv_texel[:, 0] / texture_size, 1.0 - uv_texel[:, 1] / texture_size], axis=1)
    return UVAtlas(vertices=vertices[source_vertex], faces=inverse.reshape(-1, 3).astype(np.int64),
                   uv=uv, source_vertex=source_vertex.astype(np.int64), chart=chart)
