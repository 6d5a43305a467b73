"""Rasterise a mesh in UV space: which face covers each texel, and texel colours from vertices.

The UV triangles are laid in the plane z = 0 in texel coordinates and one vertical ray per
texel centre is cast with Open3D, which gives the covering face and its barycentric
weights without a hand-written scan converter.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
from scipy import ndimage

from r2s.render.gbuffer import NO_HIT
from r2s.render.texel import uv_to_texel


def uv_raster(uv: np.ndarray, faces: np.ndarray, height: int, width: int
              ) -> tuple[np.ndarray, np.ndarray]:
    """The face covering each texel centre.

    Parameters
    ----------
    uv : (V, 2) texture coordinates (trimesh convention, see :mod:`r2s.render.texel`).
    faces : (F, 3) int indices into ``uv``.
    height, width : texture size in texels.

    Returns
    -------
    face : (H, W) int64 covering face, -1 where no face covers the texel centre.
    bary : (H, W, 3) float32 barycentric weights of the texel centre in that face.
    """
    xy = uv_to_texel(uv, height, width)
    verts = np.concatenate([xy, np.zeros((len(xy), 1))], axis=1).astype(np.float32)
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(verts)
    mesh.triangle.indices = o3d.core.Tensor(np.asarray(faces, dtype=np.int32))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(mesh)
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float32)
    rays = np.stack([cols, rows, np.ones_like(rows), np.zeros_like(rows), np.zeros_like(rows),
                     -np.ones_like(rows)], axis=-1)
    ans = scene.cast_rays(o3d.core.Tensor(rays))
    prim = ans["primitive_ids"].numpy()
    hit = np.isfinite(ans["t_hit"].numpy()) & (prim != NO_HIT)
    buv = ans["primitive_uvs"].numpy()
    bary = np.stack([1.0 - buv[..., 0] - buv[..., 1], buv[..., 0], buv[..., 1]], axis=-1)
    face = np.where(hit, prim.astype(np.int64), -1)
    bary = np.where(hit[..., None], np.clip(bary, 0.0, 1.0), 0.0).astype(np.float32)
    return face, bary


def bake_vertex_values(face: np.ndarray, bary: np.ndarray, faces: np.ndarray,
                       values: np.ndarray) -> np.ndarray:
    """(H, W, C) float32: per-vertex ``values`` (V, C) interpolated into covered texels.

    Texels no face covers are 0.
    """
    out = np.zeros(face.shape + (values.shape[1],), np.float32)
    covered = face >= 0
    tri = np.asarray(faces)[face[covered]]
    out[covered] = np.einsum("pk,pkc->pc", bary[covered].astype(np.float64),
                             np.asarray(values, dtype=np.float64)[tri])
    return out


def fill_from_nearest(texture: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Copy into every texel outside ``known`` (H, W) bool the value of the nearest known texel."""
    if known.all() or not known.any():
        return texture.copy()
    _, (rows, cols) = ndimage.distance_transform_edt(~known, return_indices=True)
    return texture[rows, cols]
