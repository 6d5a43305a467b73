"""Synthetic RGB-D views by ray casting known meshes, for the init-stage tests.

``render_view`` ray casts world-frame meshes (plus a large table slab) through a pinhole
camera; ``write_input_scene`` writes the result as a scene's ``input/`` folder following
SCENE_FORMAT.md, so the truth (every object's pose and shape) is known exactly.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import trimesh
from PIL import Image

from r2s.geometry.camera import backproject, intrinsics, look_at
from r2s.geometry.raycast import raycast_view

TABLE_COLOR = np.array([180, 170, 150], np.uint8)


@dataclass
class SynthObject:
    """One object of a synthetic scene.

    ``mesh`` is in its object frame; ``world_from_object`` places it (the truth). With
    ``prior`` the scene gets ``priors/<id>.glb`` (the prior's own frame) and, when
    ``world_from_prior`` is given, that initial pose in objects.json.
    """

    id: int
    mesh: trimesh.Trimesh
    world_from_object: np.ndarray
    color: Sequence[int] = (200, 60, 60)
    label: str = "object"
    prior: Optional[trimesh.Trimesh] = None
    world_from_prior: Optional[np.ndarray] = None


def table_slab(size_m: float = 2.0) -> trimesh.Trimesh:
    """A thin box whose top face is the plane z = 0."""
    slab = trimesh.creation.box((size_m, size_m, 0.02))
    slab.apply_translation((0, 0, -0.01))
    return slab


def default_camera(width: int = 160, height: int = 120, eye=(0.35, -0.35, 0.35),
                   target=(0.0, 0.0, 0.03), fov_y_deg: float = 45.0
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(K, world_from_camera) of a camera looking down at the table at about 35 degrees."""
    return intrinsics(width, height, fov_y_deg), look_at(eye, target)


def render_view(objects: Sequence[SynthObject], K: np.ndarray, world_from_camera: np.ndarray,
                width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rgb (H, W, 3) uint8, depth (H, W) float32 NaN = none, masks (H, W) uint8).

    Shading is flat per object with a little Lambertian variation so colours are not all
    equal; the table is id 0.
    """
    posed = []
    for obj in objects:
        m = obj.mesh.copy()
        m.apply_transform(obj.world_from_object)
        posed.append(m)
    depth, index, tri = raycast_view(posed + [table_slab()], K, world_from_camera, width, height)
    masks = np.zeros((height, width), np.uint8)
    rgb = np.zeros((height, width, 3), np.uint8)
    rgb[:] = TABLE_COLOR
    light = np.array([0.3, -0.2, 0.93])
    for k, (obj, m) in enumerate(zip(objects, posed)):
        sel = index == k
        masks[sel] = obj.id
        shade = 0.6 + 0.4 * np.clip(m.face_normals[tri[sel]] @ light, 0, 1)
        rgb[sel] = np.clip(np.asarray(obj.color)[None, :] * shade[:, None], 0, 255).astype(np.uint8)
    return rgb, depth, masks


def write_input_scene(scene: Path, objects: Sequence[SynthObject], width: int = 160,
                      height: int = 120, K: Optional[np.ndarray] = None,
                      world_from_camera: Optional[np.ndarray] = None,
                      depth_noise_m: float = 0.0, seed: int = 0) -> Path:
    """Write ``scene/input`` (rgb.png, depth.npy, masks.png, camera.json, objects.json,
    priors/) for ``objects`` on a table at z = 0. Returns ``scene``."""
    if K is None or world_from_camera is None:
        K, world_from_camera = default_camera(width, height)
    rgb, depth, masks = render_view(objects, K, world_from_camera, width, height)
    if depth_noise_m > 0:
        depth = depth + np.random.default_rng(seed).normal(0, depth_noise_m, depth.shape)
    inp = scene / "input"
    (inp / "priors").mkdir(parents=True, exist_ok=True)
    Image.fromarray(rgb).save(inp / "rgb.png")
    np.save(inp / "depth.npy", depth.astype(np.float32))
    Image.fromarray(masks).save(inp / "masks.png")
    (inp / "camera.json").write_text(json.dumps({
        "width": width, "height": height, "K": np.asarray(K).tolist(),
        "world_from_camera": np.asarray(world_from_camera).tolist(), "depth_unit_m": 0.001}))
    entries = []
    for obj in objects:
        entry: dict = {"id": obj.id, "label": obj.label}
        if obj.prior is not None:
            obj.prior.export(inp / "priors" / f"{obj.id}.glb")
            entry["prior_mesh"] = f"priors/{obj.id}.glb"
            if obj.world_from_prior is not None:
                entry["world_from_prior"] = np.asarray(obj.world_from_prior).tolist()
        entries.append(entry)
    (inp / "objects.json").write_text(json.dumps({"objects": entries}))
    return scene


def observed_points(objects: Sequence[SynthObject], obj_id: int, K: np.ndarray,
                    world_from_camera: np.ndarray, width: int = 160, height: int = 120
                    ) -> np.ndarray:
    """(N, 3) world points of one object in a ray-cast view of ``objects``."""
    _, depth, masks = render_view(objects, K, world_from_camera, width, height)
    return backproject(depth, K, world_from_camera, masks == obj_id)


def pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(translation error m, rotation error deg) between two (4, 4) poses."""
    d_rot = estimate[:3, :3].T @ truth[:3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(d_rot) - 1) / 2, -1.0, 1.0)))
    return float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3])), float(angle)


def rotation(axis: Sequence[float], angle_deg: float) -> np.ndarray:
    """(3, 3) rotation about ``axis``."""
    return trimesh.transformations.rotation_matrix(np.radians(angle_deg), axis)[:3, :3]


def pose(translation: Sequence[float] = (0, 0, 0), rot: Optional[np.ndarray] = None
         ) -> np.ndarray:
    out = np.eye(4)
    if rot is not None:
        out[:3, :3] = rot
    out[:3, 3] = translation
    return out
