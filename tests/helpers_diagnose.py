"""A small hand-made tabletop scene for the diagnose tests, with injectable effects.

Primitive objects (exact metric priors) rest on a table; depth, masks and RGB are ray cast
from a camera at 320 x 240. Effects are injected the way real data would carry them:
``depth_scale`` multiplies the rendered depth, ``camera_rotation_deg`` rotates the
*declared* camera about its centre (the image is rendered from the true one),
``table_tilt_deg`` tilts table and objects together about the world x axis.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import numpy as np
import trimesh
from PIL import Image
from scipy.spatial.transform import Rotation

from r2s.geometry.camera import intrinsics, look_at
from r2s.geometry.raycast import raycast_view
from r2s.io.input_scene import Camera, InputScene, ObjectSpec
from r2s.io.mesh_io import save_mesh

WIDTH, HEIGHT = 320, 240


def _placed(mesh: trimesh.Trimesh, xy: tuple[float, float], yaw_deg: float) -> np.ndarray:
    """world_from_object resting the mesh's lowest point on z = 0."""
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    lowest = (mesh.vertices @ pose[:3, :3].T)[:, 2].min()
    pose[:3, 3] = [xy[0], xy[1], -lowest]
    return pose


def scene_objects(with_ball: bool = True) -> list[tuple[int, trimesh.Trimesh, np.ndarray]]:
    """(id, mesh in object frame, world_from_object) of the test objects."""
    items = [
        (1, trimesh.creation.box((0.08, 0.06, 0.05)), (-0.09, 0.06), 20.0),
        (2, trimesh.creation.cylinder(0.03, 0.09, sections=32), (0.08, 0.07), 0.0),
        (3, trimesh.creation.box((0.05, 0.05, 0.11)), (0.0, -0.07), -15.0),
    ]
    if with_ball:
        items.append((4, trimesh.creation.icosphere(3, 0.035), (0.11, -0.06), 0.0))
    return [(i, m, _placed(m, xy, yaw)) for i, m, xy, yaw in items]


def render(depth_scale: float = 1.0, camera_rotation_deg: float = 0.0,
           table_tilt_deg: float = 0.0, with_ball: bool = True, noise_m: float = 0.0005,
           seed: int = 0, depth_row_error_m: float = 0.0, lens_k1: float = 0.0,
           table_size_m: float = 1.2, floor_drop_m: Optional[float] = None,
           table_thickness_m: float = 0.02, wall_y_m: Optional[float] = None) -> dict:
    """The test scene as arrays: depth (H, W), masks, K, declared and true camera poses,
    the objects and the tilt (4, 4) applied to table and objects.

    ``table_size_m``, ``table_thickness_m``: the table board; ``floor_drop_m``: a floor
    this far below the table's top, seen past its edges (None: no floor); ``wall_y_m``: a
    wall standing across the table at this y, behind the objects (None: no wall)."""
    rng = np.random.default_rng(seed)
    objects = scene_objects(with_ball)
    tilt = np.eye(4)
    tilt[:3, :3] = Rotation.from_euler("x", table_tilt_deg, degrees=True).as_matrix()
    table = trimesh.creation.box((table_size_m, table_size_m, table_thickness_m))
    table.apply_translation([0.0, 0.0, -table_thickness_m / 2])
    if floor_drop_m is not None:
        floor = trimesh.creation.box((8.0, 8.0, 0.02))
        floor.apply_translation([0.0, 0.0, -floor_drop_m - 0.01])
        table = trimesh.util.concatenate([table, floor])
    if wall_y_m is not None:
        wall = trimesh.creation.box((8.0, 0.02, 4.0))
        wall.apply_translation([0.0, wall_y_m + 0.01, 1.0])
        table = trimesh.util.concatenate([table, wall])
    table.apply_transform(tilt)
    K = intrinsics(WIDTH, HEIGHT, 50.0)
    world_from_camera = look_at([0.5, -0.35, 0.42], [0.0, 0.0, 0.03])
    posed = [m.copy().apply_transform(tilt @ pose) for _, m, pose in objects]
    depth, index, _ = raycast_view(posed + [table], K, world_from_camera, WIDTH, HEIGHT)
    ids = np.array([i for i, _, _ in objects] + [0])
    masks = np.where(index >= 0, ids[np.clip(index, 0, len(objects))], 0).astype(np.uint8)
    depth = depth + rng.normal(0.0, noise_m, depth.shape).astype(np.float32)
    depth = (depth * depth_scale).astype(np.float32)
    if depth_row_error_m:
        # an error outside the catalogue: depth reads long by a parabola in the image row
        rows = (np.arange(HEIGHT, dtype=np.float64) - (HEIGHT - 1) / 2) / ((HEIGHT - 1) / 2)
        depth = (depth + depth_row_error_m * rows[:, None] ** 2).astype(np.float32)
    if lens_k1:
        from r2s.geometry.lens import distort_image

        depth = distort_image(np.where(depth > 0, depth, np.nan), K, lens_k1).astype(np.float32)
        depth = np.where(np.isfinite(depth), depth, 0.0).astype(np.float32)
        masks = distort_image(masks, K, lens_k1, fill=0)
    declared = world_from_camera.copy()
    if camera_rotation_deg:
        declared[:3, :3] = Rotation.from_rotvec(
            np.radians(camera_rotation_deg) * np.array([1.0, 0.0, 0.0])).as_matrix() @ declared[:3, :3]
    return {"depth": depth, "masks": masks, "K": K, "declared": declared,
            "world_from_camera": world_from_camera, "objects": objects, "tilt": tilt}


def input_scene(**kwargs) -> InputScene:
    """An in-memory :class:`InputScene` of :func:`render` (priors without files)."""
    r = render(**kwargs)
    cam = Camera(K=r["K"], world_from_camera=r["declared"], width=WIDTH, height=HEIGHT)
    objs = [ObjectSpec(id=i, label=f"object_{i}") for i, _, _ in r["objects"]]
    depth = np.where(r["depth"] > 0, r["depth"], np.nan).astype(np.float32)
    return InputScene(rgb=np.zeros((HEIGHT, WIDTH, 3), np.uint8), depth_m=depth,
                      masks=r["masks"].astype(np.int32), camera=cam, objects=objs)


def write_scene(root: Path, depth_scale: float = 1.0, camera_rotation_deg: float = 0.0,
                table_tilt_deg: float = 0.0, with_ball: bool = True, noise_m: float = 0.0005,
                seed: int = 0, prior_pose_noise_m: float = 0.004,
                prior_scales: Optional[dict] = None, depth_row_error_m: float = 0.0,
                lens_k1: float = 0.0, table_size_m: float = 1.2,
                floor_drop_m: Optional[float] = None, table_thickness_m: float = 0.02) -> Path:
    """Write ``root/input`` and ``root/gt`` of the test scene; returns ``root``.

    ``prior_scales``: id -> factor by which that object's prior is too large (a prior's
    size error); ``depth_row_error_m``: an uncatalogued depth error, the depth reads long
    by this times the squared row offset from the centre (-1..1); ``lens_k1``: radial
    lens distortion of the recorded depth and masks; ``table_size_m``, ``floor_drop_m``,
    ``table_thickness_m``:
    a smaller table with a floor seen past its edges (:func:`render`)."""
    r = render(depth_scale, camera_rotation_deg, table_tilt_deg, with_ball, noise_m, seed,
               depth_row_error_m, lens_k1, table_size_m, floor_drop_m, table_thickness_m)
    rng = np.random.default_rng(seed + 1)
    objects, tilt, masks, K = r["objects"], r["tilt"], r["masks"], r["K"]
    depth, declared = r["depth"], r["declared"]
    inp = root / "input"
    (inp / "priors").mkdir(parents=True, exist_ok=True)
    np.save(inp / "depth.npy", np.where(np.isfinite(depth), depth, 0.0).astype(np.float32))
    Image.fromarray(masks).save(inp / "masks.png")
    rgb = np.full((HEIGHT, WIDTH, 3), 180, np.uint8)
    for k, (i, _, _) in enumerate(objects):
        rgb[masks == i] = (40 * k + 60, 200 - 30 * k, 90)
    Image.fromarray(rgb).save(inp / "rgb.png")
    (inp / "camera.json").write_text(json.dumps(
        {"width": WIDTH, "height": HEIGHT, "K": K.tolist(), "world_from_camera": declared.tolist(),
         "depth_unit_m": 0.001}))
    entries = []
    for i, mesh, pose in objects:
        factor = (prior_scales or {}).get(i, 1.0)
        save_mesh(mesh.copy().apply_scale(factor), inp / "priors" / f"{i}.glb")
        guess = tilt @ pose
        guess = guess.copy()
        guess[:3, 3] += rng.normal(0.0, prior_pose_noise_m, 3)
        entries.append({"id": i, "label": f"object_{i}", "prior_mesh": f"priors/{i}.glb",
                        "world_from_prior": guess.tolist()})
    (inp / "objects.json").write_text(json.dumps({"objects": entries}))

    gt = root / "gt"
    (gt / "meshes").mkdir(parents=True, exist_ok=True)
    gt_objects = []
    for i, mesh, pose in objects:
        save_mesh(mesh, gt / "meshes" / f"{i}.glb")
        gt_objects.append({"id": i, "label": f"object_{i}", "mesh": f"meshes/{i}.glb",
                           "world_from_object": (tilt @ pose).tolist(), "mass_kg": 0.2,
                           "friction": 0.8, "com_in_object": [0.0, 0.0, 0.0]})
    normal = tilt[:3, :3] @ np.array([0.0, 0.0, 1.0])
    injected = {k: v for k, v in (("depth_scale", depth_scale),
                                  ("camera_rotation_deg", camera_rotation_deg),
                                  ("table_tilt_deg", table_tilt_deg),
                                  ("depth_row_error_m", depth_row_error_m),
                                  ("lens_k1", lens_k1))
                if v != (1.0 if k == "depth_scale" else 0.0)}
    (gt / "scene.json").write_text(json.dumps(
        {"gravity": [0, 0, -9.81], "objects": gt_objects,
         "support": {"type": "plane", "point": [0, 0, 0], "normal": normal.tolist(),
                     "friction": 0.8},
         "injected_effects": injected}))
    return root


def prior_mesh(obj_id: int, with_ball: bool = True) -> Optional[trimesh.Trimesh]:
    for i, mesh, _ in scene_objects(with_ball):
        if i == obj_id:
            return mesh
    return None


def pixel_grid(K: np.ndarray, width: int, height: int, step: int = 2
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every ``step``-th pixel: (u (N,), v (N,), normalised coordinates (N, 2))."""
    v, u = np.mgrid[0:height:step, 0:width:step].astype(np.float64)
    u, v = u.ravel(), v.ravel()
    return u, v, np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]], axis=1)


def depth_to_table(x: np.ndarray, world_from_camera: np.ndarray) -> np.ndarray:
    """(N,) depth (camera z, m) at which each ray of normalised coordinates ``x`` (N, 2)
    meets the level table, the world's z = 0 plane (negative: it does not)."""
    cam_from_world = np.linalg.inv(world_from_camera)
    n_c = cam_from_world[:3, :3] @ np.array([0.0, 0.0, 1.0])
    rays = np.hstack([x, np.ones((len(x), 1))])
    return (n_c @ cam_from_world[:3, 3]) / (rays @ n_c)
