"""Ray-cast depth and instance images of world-frame meshes through a pinhole camera.

Used to make synthetic views (tests, benchmarks) and to check a reconstruction against
the observed depth. Open3D's ``RaycastingScene`` does the intersection work.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
import trimesh

from r2s.geometry.camera import pixel_rays


def raycast_view(meshes_world: list[trimesh.Trimesh], K: np.ndarray,
                 world_from_camera: np.ndarray, width: int, height: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Depth, hit mesh and hit triangle of every pixel.

    Parameters
    ----------
    meshes_world : meshes already placed in the world frame.
    K : (3, 3); world_from_camera : (4, 4) OpenCV camera; width, height : pixels.

    Returns
    -------
    depth_m : (H, W) float32 depth along the camera z axis, NaN where no mesh is hit.
    mesh_index : (H, W) int32 index into ``meshes_world`` of the hit mesh, -1 for none.
    triangle : (H, W) int64 hit triangle of that mesh, -1 for none.
    """
    scene = o3d.t.geometry.RaycastingScene()
    geometry_ids = []
    for mesh in meshes_world:
        tm = o3d.t.geometry.TriangleMesh()
        tm.vertex.positions = o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32))
        tm.triangle.indices = o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.int32))
        geometry_ids.append(scene.add_triangles(tm))
    origins, dirs = pixel_rays(K, world_from_camera, width, height)
    rays = np.concatenate([origins, dirs], axis=-1).astype(np.float32)
    ans = scene.cast_rays(o3d.core.Tensor(rays))
    t_hit = ans["t_hit"].numpy()
    gid = ans["geometry_ids"].numpy().astype(np.int64)
    prim = ans["primitive_ids"].numpy().astype(np.int64)
    hit = np.isfinite(t_hit)
    depth = np.where(hit, t_hit, np.nan).astype(np.float32)
    lookup = {g: i for i, g in enumerate(geometry_ids)}
    mesh_index = np.full(gid.shape, -1, dtype=np.int32)
    for g, i in lookup.items():
        mesh_index[hit & (gid == g)] = i
    triangle = np.where(hit, prim, -1)
    return depth, mesh_index, triangle
