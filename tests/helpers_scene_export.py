"""A small exported scene for the export-format tests: a textured 10 cm box on the table with
an upright can on it, the input camera looking at them, exported from gt/."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from helpers_export import look_at_camera, write_camera
from r2s.io.mesh_io import save_mesh
from r2s.runner.base import run_stage
from r2s.stages.export import STAGE as EXPORT, Options as ExportOptions

BOX_MASS_KG, CAN_MASS_KG = 0.5, 0.1
BOX_FRICTION, CAN_FRICTION, SUPPORT_FRICTION = 0.9, 0.6, 0.8


def textured(mesh: trimesh.Trimesh, seed: int) -> trimesh.Trimesh:
    """``mesh`` with planar UVs and a random 16x16 texture."""
    v = np.asarray(mesh.vertices)
    uv = (v[:, :2] - v[:, :2].min(0)) / np.ptp(v[:, :2], axis=0)
    pixels = np.random.default_rng(seed).integers(0, 255, (16, 16, 3), dtype=np.uint8)
    out = trimesh.Trimesh(v, np.asarray(mesh.faces), process=False)
    out.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(pixels))
    return out


def exported_scene(root: Path, box_lift_m: float = 0.0, can_lift_m: float = 0.0) -> Path:
    """Write gt/ + input/camera.json under ``root`` and export it; returns ``root/export``.

    The box stands on the table and the can on the box, in exact contact; ``box_lift_m`` and
    ``can_lift_m`` raise them (m, world z)."""
    (root / "gt" / "meshes").mkdir(parents=True)
    save_mesh(textured(trimesh.creation.box([0.1, 0.1, 0.1]), 1), root / "gt/meshes/1.glb")
    save_mesh(textured(trimesh.creation.cylinder(radius=0.02, height=0.08, sections=24), 2),
              root / "gt/meshes/2.glb")
    box_pose, can_pose = np.eye(4), np.eye(4)
    box_pose[:3, 3] = [0.02, -0.01, 0.05 + box_lift_m]
    can_pose[:3, 3] = [0.02, -0.01, 0.14 + can_lift_m]
    scene = {
        "gravity": [0, 0, -9.81],
        "objects": [
            {"id": 1, "label": "box", "mesh": "meshes/1.glb", "world_from_object":
             box_pose.tolist(), "mass_kg": BOX_MASS_KG, "friction": BOX_FRICTION,
             "com_in_object": [0, 0, 0]},
            {"id": 2, "label": "can", "mesh": "meshes/2.glb", "world_from_object":
             can_pose.tolist(), "mass_kg": CAN_MASS_KG, "friction": CAN_FRICTION,
             "com_in_object": [0, 0, 0]},
        ],
        "support": {"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1],
                    "friction": SUPPORT_FRICTION},
    }
    (root / "gt" / "scene.json").write_text(json.dumps(scene))
    K, world_from_camera = look_at_camera([0.5, -0.4, 0.4], [0.02, -0.01, 0.05], 160, 120)
    K[0, 2] += 3.0  # principal point off the centre, to check its conversion
    K[1, 2] -= 4.0
    write_camera(root / "input", K, world_from_camera, 160, 120)
    # no observation check: this input/ has a camera but no image
    run_stage(EXPORT, root, ExportOptions(source="gt", observation=False))
    return root / "export"
