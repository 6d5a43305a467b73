"""Synthetic textured scenes for the texture and render tests and the texture benchmark.

Objects get a chart atlas and a texture made from a smooth colour field of 3D position
(so the "true" appearance is known everywhere, seen or not); the observed image is the
albedo render of the true textures (plus optional noise) over a flat grey table, and the
masks are the rendered instance ids. ``write_scene`` writes ``input/`` plus an ``init/``
state (with a manifest record) in the contract formats, straight with json / PIL / trimesh.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Sequence

import numpy as np
import trimesh
from PIL import Image

from r2s.geometry.camera import intrinsics, look_at, pixel_rays, transform_points
from r2s.render.gbuffer import rasterize
from r2s.render.shade import MeshColour, shade
from r2s.texture.bake import bake_vertex_values, fill_from_nearest, uv_raster
from r2s.texture.textured import to_trimesh
from r2s.texture.uv import chart_atlas

TABLE_RGB = (0.55, 0.55, 0.52)


def pose(translation: Sequence[float], yaw_rad: float = 0.0) -> np.ndarray:
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    out = np.eye(4)
    out[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    out[:3, 3] = translation
    return out


def colour_field(seed: int) -> Callable[[np.ndarray], np.ndarray]:
    """A smooth RGB field on object-frame points (N, 3) -> (N, 3) in [0.1, 0.9]."""
    rng = np.random.default_rng(seed)
    base = rng.uniform(0.3, 0.7, 3)
    freq = rng.normal(0.0, 25.0, (3, 3))
    phase = rng.uniform(0, 2 * np.pi, 3)

    def field(points: np.ndarray) -> np.ndarray:
        wave = np.sin(np.asarray(points) @ freq.T + phase)
        return np.clip(base + 0.25 * wave, 0.1, 0.9)

    return field


@dataclass
class SynthObject:
    """One object: object-frame mesh with UVs, its true texture, pose and id."""

    id: int
    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    texture: np.ndarray
    world_from_object: np.ndarray
    field: Callable[[np.ndarray], np.ndarray]

    def trimesh(self, texture: Optional[np.ndarray] = None) -> trimesh.Trimesh:
        return to_trimesh(self.vertices, self.faces, self.uv,
                          self.texture if texture is None else texture)


def textured_object(obj_id: int, mesh: trimesh.Trimesh, world_from_object: np.ndarray,
                    texture_size: int, seed: int) -> SynthObject:
    """Atlas + baked colour field for ``mesh`` (object frame)."""
    atlas = chart_atlas(mesh.vertices, mesh.faces, texture_size)
    face, bary = uv_raster(atlas.uv, atlas.faces, texture_size, texture_size)
    points = bake_vertex_values(face, bary, atlas.faces, atlas.vertices)
    field = colour_field(seed)
    texture = field(points.reshape(-1, 3)).reshape(points.shape).astype(np.float32)
    texture = fill_from_nearest(texture, face >= 0)
    return SynthObject(obj_id, atlas.vertices, atlas.faces, atlas.uv, texture,
                       np.asarray(world_from_object, float), field)


@dataclass
class SynthView:
    K: np.ndarray
    world_from_camera: np.ndarray
    width: int
    height: int
    rgb: np.ndarray
    masks: np.ndarray
    depth_m: np.ndarray


def table_camera(width: int, height: int, distance_m: float = 0.6,
                 elevation_deg: float = 50.0) -> tuple[np.ndarray, np.ndarray]:
    """K and world_from_camera of a camera looking at the origin from above and in front."""
    el = np.radians(elevation_deg)
    eye = np.array([0.0, -distance_m * np.cos(el), distance_m * np.sin(el)])
    return intrinsics(width, height, 45.0), look_at(eye, np.zeros(3))


def render_view(objects: Sequence[SynthObject], K: np.ndarray, world_from_camera: np.ndarray,
                width: int, height: int, noise_sigma: float = 0.0, seed: int = 0,
                textures: Optional[Sequence[np.ndarray]] = None) -> SynthView:
    """Observed image (true textures over a grey table at z = 0), masks and depth."""
    class Posed:
        def __init__(self, o: SynthObject):
            self.vertices = transform_points(o.world_from_object, o.vertices)
            self.faces = o.faces

    gb = rasterize([Posed(o) for o in objects], K, world_from_camera, width, height)
    textures = [o.texture for o in objects] if textures is None else textures
    rgb = shade(gb, [o.faces for o in objects],
                [MeshColour(uv=o.uv, texture=t) for o, t in zip(objects, textures)],
                background_rgb=TABLE_RGB)
    if noise_sigma > 0:
        rgb = rgb + np.random.default_rng(seed).normal(0.0, noise_sigma, rgb.shape)
    rgb8 = np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8)
    ids = np.asarray([0] + [o.id for o in objects], np.int32)
    masks = ids[gb.object_index + 1]
    origins, dirs = pixel_rays(K, world_from_camera, width, height)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_table = -origins[..., 2] / dirs[..., 2]
    depth = np.where(gb.hit, gb.depth_m, np.where(t_table > 0, t_table, np.nan)).astype(np.float32)
    return SynthView(K, world_from_camera, width, height, rgb8, masks, depth)


def write_scene(scene: Path, objects: Sequence[SynthObject], view: SynthView,
                init_meshes: Sequence[trimesh.Trimesh]) -> Path:
    """Write ``scene/input`` and an ``init/`` state (object-frame ``init_meshes``) + manifest."""
    inp = scene / "input"
    inp.mkdir(parents=True)
    (inp / "camera.json").write_text(json.dumps({
        "width": view.width, "height": view.height, "K": np.asarray(view.K).tolist(),
        "world_from_camera": np.asarray(view.world_from_camera).tolist(), "depth_unit_m": 0.001}))
    Image.fromarray(view.rgb).save(inp / "rgb.png")
    Image.fromarray(view.masks.astype(np.uint8)).save(inp / "masks.png")
    np.save(inp / "depth.npy", view.depth_m)
    init = scene / "init"
    (init / "meshes").mkdir(parents=True)
    entries = []
    for obj, mesh in zip(objects, init_meshes):
        mesh.export(init / "meshes" / f"{obj.id}.glb")
        entries.append({"id": obj.id, "label": f"object_{obj.id}", "mesh": f"meshes/{obj.id}.glb",
                        "world_from_object": obj.world_from_object.tolist(), "mass_kg": 0.1,
                        "source": "completed"})
    (init / "state.json").write_text(json.dumps({
        "stage": "init", "gravity": [0, 0, -9.81],
        "support": {"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1], "friction": 0.8},
        "objects": entries}))
    (scene / "manifest.json").write_text(json.dumps(
        {"format": "r2s-manifest", "version": 1, "stages": {"init": {"status": "done"}}}))
    return scene


def vertex_coloured(obj: SynthObject, gain: float = 0.7, offset: float = 0.1) -> trimesh.Trimesh:
    """The object's shape with vertex colours: its colour field, dulled (a poor initial guess)."""
    rgb = np.clip(gain * obj.field(obj.vertices) + offset, 0, 1)
    colours = np.concatenate([rgb * 255, np.full((len(rgb), 1), 255)], axis=1).astype(np.uint8)
    return trimesh.Trimesh(obj.vertices, obj.faces, vertex_colors=colours, process=False)


def six_object_scene(texture_size: int = 256, seed: int = 0) -> list[SynthObject]:
    """Six objects (boxes, cylinders, spheres) on a table, some hiding parts of others."""
    shapes = [
        trimesh.creation.box((0.08, 0.06, 0.10)),
        trimesh.creation.cylinder(0.035, 0.12, sections=48),
        trimesh.creation.icosphere(3, 0.045),
        trimesh.creation.box((0.12, 0.05, 0.04)),
        trimesh.creation.cylinder(0.05, 0.05, sections=48),
        trimesh.creation.icosphere(3, 0.035),
    ]
    places = [(-0.08, 0.05), (0.02, 0.07), (0.10, 0.04), (-0.06, -0.05), (0.05, -0.04),
              (0.13, -0.06)]
    objects = []
    for k, (mesh, (x, y)) in enumerate(zip(shapes, places)):
        z = -mesh.bounds[0, 2]
        objects.append(textured_object(k + 1, mesh, pose((x, y, z), 0.4 * k), texture_size,
                                       seed * 100 + k))
    return objects
