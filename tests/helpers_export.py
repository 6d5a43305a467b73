"""Hand-made ``export/``, ``gt/`` and ``input/camera.json`` folders for the evaluate tests.

Written straight from SCENE_FORMAT.md (json + trimesh), independent of r2s's export writer.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import trimesh


def pose(translation: Sequence[float] = (0, 0, 0),
         rotation: Optional[np.ndarray] = None) -> np.ndarray:
    """(4, 4) rigid transform."""
    out = np.eye(4)
    if rotation is not None:
        out[:3, :3] = rotation
    out[:3, 3] = translation
    return out


def rot_x(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


@dataclass
class Obj:
    """One object to write. ``mesh`` is in the object frame; ``pieces`` default to its hull."""

    id: int
    mesh: trimesh.Trimesh
    world_from_object: np.ndarray
    mass_kg: float = 0.2
    friction: float = 0.8
    restitution: float = 0.0
    com_in_object: Sequence[float] = (0.0, 0.0, 0.0)
    label: str = ""
    source: Optional[str] = None
    pieces: list = field(default_factory=list)


def write_export(export_dir: Path, objects: Sequence[Obj], support_point=(0, 0, 0),
                 support_normal=(0, 0, 1), support_friction: float = 0.8,
                 gravity=(0, 0, -9.81)) -> Path:
    """Write ``export_dir/scene.json`` + meshes/<id>.glb + collision/<id>_<k>.obj."""
    export_dir = Path(export_dir)
    (export_dir / "meshes").mkdir(parents=True, exist_ok=True)
    (export_dir / "collision").mkdir(parents=True, exist_ok=True)
    entries = []
    for obj in objects:
        visual = f"meshes/{obj.id}.glb"
        obj.mesh.export(export_dir / visual)
        pieces = obj.pieces or [obj.mesh.convex_hull]
        collision = []
        for k, piece in enumerate(pieces):
            rel = f"collision/{obj.id}_{k}.obj"
            piece.export(export_dir / rel)
            collision.append(rel)
        entry = {
            "id": obj.id, "label": obj.label or f"object_{obj.id}",
            "visual_mesh": visual, "collision_meshes": collision,
            "world_from_object": np.asarray(obj.world_from_object).tolist(),
            "mass_kg": obj.mass_kg, "com_in_object": list(map(float, obj.com_in_object)),
            "friction": obj.friction, "restitution": obj.restitution,
        }
        if obj.source is not None:
            entry["source"] = obj.source
        entries.append(entry)
    scene = {
        "format": "r2s-scene", "version": 1, "gravity": list(map(float, gravity)),
        "support": {"type": "plane", "point": list(map(float, support_point)),
                    "normal": list(map(float, support_normal)), "friction": support_friction},
        "objects": entries,
    }
    (export_dir / "scene.json").write_text(json.dumps(scene, indent=1))
    return export_dir


def write_gt(gt_dir: Path, objects: Sequence[Obj]) -> Path:
    """Write ``gt_dir/scene.json`` + meshes/<id>.glb (plane support at z = 0)."""
    gt_dir = Path(gt_dir)
    (gt_dir / "meshes").mkdir(parents=True, exist_ok=True)
    entries = []
    for obj in objects:
        rel = f"meshes/{obj.id}.glb"
        obj.mesh.export(gt_dir / rel)
        entries.append({
            "id": obj.id, "label": obj.label or f"object_{obj.id}", "mesh": rel,
            "world_from_object": np.asarray(obj.world_from_object).tolist(),
            "mass_kg": obj.mass_kg, "friction": obj.friction,
            "com_in_object": list(map(float, obj.com_in_object)),
            "injected_effect": {"kind": "none"},
        })
    scene = {"gravity": [0, 0, -9.81], "objects": entries,
             "support": {"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1],
                         "friction": 0.8}}
    (gt_dir / "scene.json").write_text(json.dumps(scene, indent=1))
    return gt_dir


def look_at_camera(eye: Sequence[float], target: Sequence[float], width: int = 160,
                   height: int = 120, fov_x_deg: float = 60.0) -> tuple[np.ndarray, np.ndarray]:
    """(K (3, 3), world_from_camera (4, 4) OpenCV) for a camera at ``eye`` looking at ``target``."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    world_from_camera = pose(eye, np.stack([x, y, z], axis=1))
    f = 0.5 * width / np.tan(np.radians(fov_x_deg) / 2)
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])
    return K, world_from_camera


def write_camera(input_dir: Path, K: np.ndarray, world_from_camera: np.ndarray, width: int,
                 height: int) -> Path:
    input_dir = Path(input_dir)
    input_dir.mkdir(parents=True, exist_ok=True)
    path = input_dir / "camera.json"
    path.write_text(json.dumps({"width": width, "height": height, "K": np.asarray(K).tolist(),
                                "world_from_camera": np.asarray(world_from_camera).tolist(),
                                "depth_unit_m": 0.001}))
    return path
