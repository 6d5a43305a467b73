"""Write ``export/`` exactly as SCENE_FORMAT.md says, plus one URDF per object.

Layout (paths in scene.json relative to ``export/``)::

    export/scene.json
    export/meshes/<id>.glb          visual mesh, object frame (colours/texture kept)
    export/meshes/<id>.obj          the same shape as OBJ (for URDF visuals)
    export/collision/<id>_<k>.obj   convex pieces, object frame
    export/visual/<id>.obj|mtl|png  the textured visual mesh as OBJ (URDF and MJCF visuals)
    export/urdf/<id>.urdf           single-link URDF with explicit inertia, textured visual
    export/scene.xml                the same scene as MJCF (MuJoCo, r2s.io.mjcf)
    export/scene.usda               the same scene as USD (UsdPhysics, r2s.io.usd_scene)
    export/scene.glb                all visual meshes in one glTF, Y up (r2s.io.scene_glb)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import trimesh

from r2s.io.atomic import atomic_write_json, atomic_write_text
from r2s.io.mesh_io import save_mesh, untextured
from r2s.io.mjcf import MjcfObject, write_mjcf
from r2s.io.scene_glb import GlbObject, write_scene_glb
from r2s.io.urdf import urdf_text
from r2s.io.paths import EXPORT_SCENE_FILE
from r2s.io.usd_scene import UsdObject, write_usd
from r2s.io.visual_mesh import write_visual_obj


@dataclass
class ExportBody:
    """Everything export writes for one object (object frame, SI units).

    collision_pieces : convex meshes; world_from_object : (4, 4); com_in_object : (3,);
    inertia_about_com : (3, 3); extra : additional keys for scene.json (e.g. "source").
    """

    id: int
    label: str
    visual_mesh: trimesh.Trimesh
    collision_pieces: Sequence[trimesh.Trimesh]
    world_from_object: np.ndarray
    mass_kg: float
    com_in_object: np.ndarray
    inertia_about_com: np.ndarray
    friction: float
    restitution: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)


def write_export(out_dir: Path, gravity: Sequence[float], support: dict,
                 bodies: Sequence[ExportBody], camera=None) -> dict:
    """Write the export folder into ``out_dir``; returns the scene.json content.

    ``camera``: the input camera (:class:`r2s.io.input_scene.Camera`) placed in the MJCF and
    USD scenes, or None."""
    out_dir = Path(out_dir)
    objects, mj_objects, usd_objects = [], [], []
    for body in bodies:
        visual = write_visual_obj(body.visual_mesh, out_dir, str(body.id))
        visual_rel = f"meshes/{body.id}.glb"
        save_mesh(body.visual_mesh, out_dir / visual_rel)
        save_mesh(untextured(body.visual_mesh), out_dir / f"meshes/{body.id}.obj")
        collision_rel = []
        for k, piece in enumerate(body.collision_pieces):
            rel = f"collision/{body.id}_{k}.obj"
            save_mesh(piece, out_dir / rel)
            collision_rel.append(rel)
        atomic_write_text(
            out_dir / f"urdf/{body.id}.urdf",
            urdf_text(f"object_{body.id}", f"../{visual.obj}",
                      [f"../{r}" for r in collision_rel], body.mass_kg, body.com_in_object,
                      body.inertia_about_com, body.friction, body.restitution),
        )
        entry = {
            "id": int(body.id),
            "label": body.label,
            "visual_mesh": visual_rel,
            "collision_meshes": collision_rel,
            "urdf": f"urdf/{body.id}.urdf",
            "world_from_object": np.asarray(body.world_from_object, dtype=float).tolist(),
            "mass_kg": float(body.mass_kg),
            "com_in_object": [float(x) for x in body.com_in_object],
            "inertia_about_com": np.asarray(body.inertia_about_com, dtype=float).tolist(),
            "friction": float(body.friction),
            "restitution": float(body.restitution),
        }
        entry.update(body.extra)
        objects.append(entry)
        mj_objects.append(MjcfObject(
            id=int(body.id), world_from_object=np.asarray(body.world_from_object, float),
            mass_kg=float(body.mass_kg), com_in_object=np.asarray(body.com_in_object, float),
            inertia_about_com=np.asarray(body.inertia_about_com, float),
            friction=float(body.friction), collision_meshes=collision_rel,
            collision_bounds=[np.asarray(p.bounds) for p in body.collision_pieces],
            visual_obj=visual.obj, visual_png=visual.png, rgba=visual.rgba))
        usd_objects.append(UsdObject(
            id=int(body.id), label=body.label,
            world_from_object=np.asarray(body.world_from_object, float),
            mass_kg=float(body.mass_kg), com_in_object=np.asarray(body.com_in_object, float),
            inertia_about_com=np.asarray(body.inertia_about_com, float),
            friction=float(body.friction), restitution=float(body.restitution),
            pieces=list(body.collision_pieces), visual_mesh=body.visual_mesh,
            texture_rel=visual.png, rgba=visual.rgba))
    scene = {
        "format": "r2s-scene",
        "version": 1,
        "gravity": [float(g) for g in gravity],
        "support": support,
        "objects": objects,
    }
    atomic_write_json(out_dir / EXPORT_SCENE_FILE, scene)
    write_mjcf(out_dir, mj_objects, scene["gravity"], support, camera)
    write_usd(out_dir, usd_objects, scene["gravity"], support, camera)
    write_scene_glb(out_dir, [GlbObject(int(b.id), b.visual_mesh,
                                        np.asarray(b.world_from_object, float))
                              for b in bodies], support)
    return scene
