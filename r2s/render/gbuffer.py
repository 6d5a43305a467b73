"""A per-pixel G-buffer of world-frame meshes seen through a pinhole camera.

One ray per pixel centre (pixel ``(u, v)`` is column ``u``, row ``v``, centres at integer
coordinates, OpenCV camera: x right, y down, z forward) is cast against every mesh at once
with Open3D's ``RaycastingScene``, so occlusion between objects is resolved by the nearest
hit. Since geometry is fixed during texture refinement, this is done once.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import open3d as o3d

from r2s.geometry.camera import pixel_rays

NO_HIT = np.iinfo(np.uint32).max
"""Open3D's id for "no geometry" in ``geometry_ids`` / ``primitive_ids``."""


@dataclass(frozen=True)
class GBuffer:
    """What each pixel sees.

    Attributes
    ----------
    object_index : (H, W) int32 index into the mesh list of the nearest hit mesh, -1 = none.
    face : (H, W) int64 hit triangle of that mesh, -1 = none.
    bary : (H, W, 3) float32 barycentric weights of the hit point on the face's three
        vertices (zeros where nothing is hit).
    depth_m : (H, W) float32 depth along the camera z axis, NaN where nothing is hit.
    """

    object_index: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    depth_m: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """(H, W) bool, True where some mesh is seen."""
        return self.object_index >= 0

    @property
    def shape(self) -> tuple[int, int]:
        return self.object_index.shape


def _o3d_mesh(vertices: np.ndarray, faces: np.ndarray) -> o3d.t.geometry.TriangleMesh:
    tm = o3d.t.geometry.TriangleMesh()
    tm.vertex.positions = o3d.core.Tensor(np.ascontiguousarray(vertices, dtype=np.float32))
    tm.triangle.indices = o3d.core.Tensor(np.ascontiguousarray(faces, dtype=np.int32))
    return tm


def rasterize(meshes_world: Sequence, K: np.ndarray, world_from_camera: np.ndarray,
              width: int, height: int) -> GBuffer:
    """Ray-cast a G-buffer of world-frame meshes.

    Parameters
    ----------
    meshes_world : objects with ``vertices`` (V, 3) world frame and ``faces`` (F, 3)
        (``trimesh.Trimesh`` or anything shaped alike), in the order of the returned
        ``object_index``.
    K : (3, 3) intrinsics, pixels.
    world_from_camera : (4, 4) OpenCV camera to world.
    width, height : image size in pixels.

    Returns
    -------
    :class:`GBuffer` of shape (height, width).
    """
    scene = o3d.t.geometry.RaycastingScene()
    geometry_ids = []
    for mesh in meshes_world:
        faces = np.asarray(mesh.faces)
        if len(faces) == 0:
            geometry_ids.append(None)
            continue
        geometry_ids.append(scene.add_triangles(_o3d_mesh(np.asarray(mesh.vertices), faces)))
    shape = (height, width)
    if all(g is None for g in geometry_ids):
        return GBuffer(np.full(shape, -1, np.int32), np.full(shape, -1, np.int64),
                       np.zeros(shape + (3,), np.float32), np.full(shape, np.nan, np.float32))
    origins, dirs = pixel_rays(K, world_from_camera, width, height)
    rays = np.concatenate([origins, dirs], axis=-1).astype(np.float32)
    ans = scene.cast_rays(o3d.core.Tensor(rays))
    t_hit = ans["t_hit"].numpy()
    gid = ans["geometry_ids"].numpy()
    prim = ans["primitive_ids"].numpy()
    uv = ans["primitive_uvs"].numpy()
    hit = np.isfinite(t_hit) & (gid != NO_HIT)
    object_index = np.full(shape, -1, np.int32)
    for index, g in enumerate(geometry_ids):
        if g is not None:
            object_index[hit & (gid == g)] = index
    hit = object_index >= 0
    face = np.where(hit, prim.astype(np.int64), -1)
    bary = np.stack([1.0 - uv[..., 0] - uv[..., 1], uv[..., 0], uv[..., 1]], axis=-1)
    bary = np.where(hit[..., None], np.clip(bary, 0.0, 1.0), 0.0).astype(np.float32)
    depth = np.where(hit, t_hit, np.nan).astype(np.float32)
    return GBuffer(object_index=object_index, face=face, bary=bary, depth_m=depth)


def interpolate(gbuffer: GBuffer, index: int, faces: np.ndarray, attribute: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Barycentric interpolation of a per-vertex (or per-wedge) attribute at the pixels of one mesh.

    Parameters
    ----------
    gbuffer : from :func:`rasterize`.
    index : which mesh (position in the list given to :func:`rasterize`).
    faces : (F, 3) int indices into ``attribute`` (e.g. the mesh's faces, or UV faces).
    attribute : (N, C) values per vertex.

    Returns
    -------
    pixels : (P, 2) int64 ``(row, col)`` of the pixels that see this mesh, row-major order.
    values : (P, C) float64 interpolated attribute at those pixels.
    """
    rows, cols = np.nonzero(gbuffer.object_index == index)
    tri = np.asarray(faces)[gbuffer.face[rows, cols]]
    attr = np.asarray(attribute, dtype=np.float64)
    w = gbuffer.bary[rows, cols].astype(np.float64)
    values = np.einsum("pk,pkc->pc", w, attr[tri])
    return np.stack([rows, cols], axis=1).astype(np.int64), values
