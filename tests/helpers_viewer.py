"""A small hand-made scene for the viewer tests: input/, export/, graph/, evaluate/ options.

Three boxes on the plane z = 0 seen by a tilted camera: box 1 (blue) and box 2 (yellow)
rest on the plane, box 3 (grey) starts ``DROP_M`` above it and falls when rolled out. The
input depth is the plane itself (analytic ray-plane intersection), coloured as a
checkerboard of ``CHECKER_M`` squares, so every observed point and colour is known.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from tests.helpers_export import Obj, look_at_camera, pose, write_export

DROP_M = 0.05
CHECKER_M = 0.05
CHECKER_RGB = ((150, 150, 150), (90, 90, 90))
BOX_RGB = {1: (40, 60, 230), 2: (230, 200, 30), 3: (160, 160, 160)}
WIDTH, HEIGHT = 160, 120


def checker_rgb(xy_m: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 checkerboard colour at world (x, y) (N, 2)."""
    parity = (np.floor(xy_m[:, 0] / CHECKER_M) + np.floor(xy_m[:, 1] / CHECKER_M)) % 2
    return np.where(parity[:, None] == 0, CHECKER_RGB[0], CHECKER_RGB[1]).astype(np.uint8)


def _box(extents: tuple, rgb: tuple) -> trimesh.Trimesh:
    mesh = trimesh.creation.box(extents=extents)
    mesh.visual.vertex_colors = np.tile([*rgb, 255], (len(mesh.vertices), 1)).astype(np.uint8)
    return mesh


def write_viewer_scene(scene: Path, rollout_s: float = 1.0) -> Path:
    scene = Path(scene)
    inp = scene / "input"
    inp.mkdir(parents=True)
    K, world_from_camera = look_at_camera((0.0, -0.45, 0.35), (0.0, 0.0, 0.0), WIDTH, HEIGHT)
    (inp / "camera.json").write_text(json.dumps(
        {"width": WIDTH, "height": HEIGHT, "K": K.tolist(),
         "world_from_camera": world_from_camera.tolist(), "depth_unit_m": 0.001}))
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    rays_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    rays_world = rays_cam @ world_from_camera[:3, :3].T
    eye = world_from_camera[:3, 3]
    depth = -eye[2] / rays_world[..., 2]                   # camera z = 1 along each ray
    depth[depth <= 0] = np.nan
    np.save(inp / "depth.npy", depth.astype(np.float32))
    hit = eye + depth[..., None] * rays_world
    rgb = checker_rgb(np.nan_to_num(hit[..., :2]).reshape(-1, 2)).reshape(HEIGHT, WIDTH, 3)
    Image.fromarray(rgb).save(inp / "rgb.png")
    masks = np.zeros((HEIGHT, WIDTH), np.uint8)
    masks[50:70, 70:90] = 1
    Image.fromarray(masks).save(inp / "masks.png")

    objects = [
        Obj(1, _box((0.06, 0.06, 0.06), BOX_RGB[1]), pose((-0.05, 0.0, 0.03)), label="blue_box"),
        Obj(2, _box((0.04, 0.04, 0.08), BOX_RGB[2]), pose((0.05, 0.0, 0.04)), label="tall_box"),
        Obj(3, _box((0.04, 0.04, 0.04), BOX_RGB[3]), pose((0.0, 0.08, 0.02 + DROP_M)),
            label="falling_box"),
    ]
    write_export(scene / "export", objects)
    graph = {
        "format": "r2s-contact-graph", "version": 1, "root": 0, "up": [0, 0, 1],
        "plane_basis": [[1, 0, 0], [0, 1, 0]], "plane_point": [0, 0, 0],
        "nodes": [{"id": 0, "label": "table", "is_root": True},
                  {"id": 1, "label": "blue_box", "parent": 0},
                  {"id": 2, "label": "tall_box", "parent": 0},
                  {"id": 3, "label": "falling_box", "parent": 0}],
        "support_edges": [
            {"child": c, "parent": 0, "likelihood": 1.0, "d_gap": 0.0, "d_com": 0.0,
             "gap_m": 0.0, "com_distance_m": 0.0, "plane_height_m": 0.0, "in_tree": True}
            for c in (1, 2, 3)],
        "proximity_edges": [{"a": 1, "b": 2, "support": False}],
    }
    (scene / "graph").mkdir()
    (scene / "graph" / "contact_graph.json").write_text(json.dumps(graph))
    (scene / "evaluate").mkdir()
    (scene / "evaluate" / "metrics.json").write_text(json.dumps(
        {"format": "r2s-metrics", "options": {"duration_s": rollout_s, "rate_hz": 240.0}}))
    return scene
