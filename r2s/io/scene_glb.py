"""The whole scene as one textured glTF binary: ``export/scene.glb``.

glTF is Y up (metres); r2s's world is Z up. The file's root transform is applied to the
vertices of each node: ``Y_UP_FROM_Z_UP`` maps world (x, y, z) to glTF (x, z, -y). Each object
is a node ``object_<id>`` holding its visual mesh in the object frame with the matrix
``Y_UP_FROM_Z_UP @ world_from_object``; the support is a square ``support`` node (1 m side,
centred under the objects) in the support plane.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import trimesh

from r2s.io.atomic import atomic_write_bytes
from r2s.io.mesh_io import fast_png_textures
from r2s.io.mjcf import plane_rotation

Y_UP_FROM_Z_UP = np.array([[1.0, 0.0, 0.0, 0.0],
                           [0.0, 0.0, 1.0, 0.0],
                           [0.0, -1.0, 0.0, 0.0],
                           [0.0, 0.0, 0.0, 1.0]])
"""(4, 4) r2s world (Z up) to glTF (Y up): x stays, y_gltf = z, z_gltf = -y."""

SUPPORT_SIDE_M = 1.0


@dataclass(frozen=True)
class GlbObject:
    """One object: its visual mesh (object frame) and (4, 4) world_from_object."""

    id: int
    visual_mesh: trimesh.Trimesh
    world_from_object: np.ndarray


def support_quad(support: dict, centre_world: np.ndarray, side_m: float = SUPPORT_SIDE_M
                 ) -> tuple[trimesh.Trimesh, np.ndarray]:
    """A square in the support plane (mesh in its own frame) and its (4, 4) world pose,
    centred on ``centre_world`` projected onto the plane."""
    half = 0.5 * side_m
    quad = trimesh.Trimesh(vertices=[[-half, -half, 0], [half, -half, 0], [half, half, 0],
                                     [-half, half, 0]], faces=[[0, 1, 2], [0, 2, 3]],
                           process=False)
    quad.visual = trimesh.visual.ColorVisuals(quad, face_colors=[140, 128, 115, 255])
    n = np.asarray(support["normal"], dtype=float)
    n /= np.linalg.norm(n)
    p = np.asarray(support["point"], dtype=float)
    c = np.asarray(centre_world, dtype=float)
    pose = np.eye(4)
    pose[:3, :3] = plane_rotation(n)
    pose[:3, 3] = c - n * float((c - p) @ n)
    return quad, pose


def scene_glb_bytes(objects: Sequence[GlbObject], support: dict) -> bytes:
    """The combined scene as GLB bytes (see the module docstring for the frames)."""
    scene = trimesh.Scene()
    centres = [np.asarray(o.world_from_object)[:3, 3] for o in objects]
    quad, quad_pose = support_quad(support, np.mean(centres, axis=0) if centres else
                                   np.asarray(support["point"], dtype=float))
    scene.add_geometry(quad, node_name="support", geom_name="support",
                       transform=Y_UP_FROM_Z_UP @ quad_pose)
    for o in objects:
        scene.add_geometry(o.visual_mesh, node_name=f"object_{int(o.id)}",
                           geom_name=f"object_{int(o.id)}",
                           transform=Y_UP_FROM_Z_UP @ np.asarray(o.world_from_object, float))
    fast_png_textures(o.visual_mesh for o in objects)
    return scene.export(file_type="glb")


def write_scene_glb(export_dir: Path, objects: Sequence[GlbObject], support: dict) -> Path:
    path = Path(export_dir) / "scene.glb"
    atomic_write_bytes(path, scene_glb_bytes(objects, support))
    return path
