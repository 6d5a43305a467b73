"""An observed push, made on the ground truth of a synthetic scene (``r2s synth --push``).

One object resting on the table is pushed horizontally (parallel to the support plane),
aimed at its centre of mass and low enough not to tip it, by a sphere moving at a few
cm/s, so that it slides a few cm.
The push is simulated on ``gt/`` exported as is (so friction, COM and table-tilt effects
act) with the same pusher as ``r2s predict`` (:mod:`r2s.interaction.push`), and the scene
after it is rendered by the true camera with the same renderer and depth noise as the
image before (so depth effects act too). Written (docs/interaction.md)::

    input/interaction/{push.json, depth_after.png, masks_after.png, observed.json}
    gt/push.json    true final world_from_object and COM displacement of every object,
                    the pushed id, the action

``observed.json`` names only the pushed object (what the operator knows); the objects'
motion is for r2s to measure from the images (:mod:`r2s.interaction.track`).

Which object: among the visible objects that rest on the table and are not ball-like,
each pushed away from the camera, towards it and to either side; the push that moves its object most
while moving every other object least (and does not topple it) is kept.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import pybullet as pb
import trimesh

from r2s.errors import R2SError
from r2s.io.push_action import EndEffector, PushAction, Waypoint
from r2s.sim.export_scene import export_ground_truth
from r2s.interaction.push import replay_push
from r2s.io.atomic import atomic_write_json, commit_dir, recover_dir, scratch_dir
from r2s.io.input_scene import load_camera
from r2s.io.mesh_io import load_mesh
from r2s.io.paths import ScenePaths
from r2s.io.scene_json import read_gt_scene
from r2s.metrics.stability import rotation_angle_deg
from r2s.sim.pybullet_bodies import connect_direct
from r2s.sim.pybullet_scene import load_export_scene
from r2s.synth import appearance, depth_noise
from r2s.synth.files import depth_png, write_png, write_textured_obj
from r2s.synth.physics import plane_rotation
from r2s.synth.render import Lighting, Visual, render

PUSH_NOISE_STREAM = 100
"""Random stream of the after image's depth noise: ``default_rng([seed, 100])``."""
TOPPLED_DEG = 45.0
TURNS_DEG = (0.0, 90.0, -90.0, 180.0)
"""Push directions tried, turned from "away from the camera" about the table normal."""


@dataclass(frozen=True)
class PushSettings:
    """How to push: pusher ``radius_m``, ``speed_mps``; the pusher starts ``approach_m``
    behind the object and ends ``travel_m`` past the object's back (so the object moves
    about ``travel_m``); the scene then settles ``settle_s``. The pusher's centre is at
    the COM's height above the table but at most ``max_height_m`` (a tall box pushed at
    its COM tips over once friction x COM height exceeds half its base)."""

    speed_mps: float = 0.08
    travel_m: float = 0.05
    approach_m: float = 0.02
    radius_m: float = 0.015
    settle_s: float = 1.0
    max_height_m: float = 0.025


@dataclass(frozen=True)
class PushOutcome:
    """A simulated candidate: the action, final (4, 4) pose per id, COM displacements (3,)."""

    pushed_id: int
    action: PushAction
    final: dict
    com_displacement_m: dict
    turned_deg: float

    def score(self) -> float:
        """Own COM displacement minus 5 x the largest of the others', metres."""
        own = float(np.linalg.norm(self.com_displacement_m[self.pushed_id]))
        others = [float(np.linalg.norm(d)) for i, d in self.com_displacement_m.items()
                  if i != self.pushed_id]
        return own - 5.0 * max(others, default=0.0)


def plan_push(vertices_world: np.ndarray, com_world: np.ndarray, direction: np.ndarray,
              support_point: np.ndarray, support_normal: np.ndarray,
              settings: PushSettings = PushSettings()) -> PushAction:
    """A straight push through the COM along ``direction`` (projected onto the support plane).

    Parameters
    ----------
    vertices_world : (V, 3) the object's surface points, world frame.
    com_world : (3,) its centre of mass.
    direction : (3,) push direction (need not be unit or in the plane).
    support_point, support_normal : (3,) the table plane (normal up).

    The pusher centre moves at the COM's height above the table, at most
    ``settings.max_height_m`` and at least its radius + 3 mm (so it never scrapes the
    table), from ``approach_m`` behind the object's rearmost point to ``travel_m`` past it.
    """
    n = np.asarray(support_normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    d = np.asarray(direction, dtype=np.float64)
    d = d - (d @ n) * n
    d = d / np.linalg.norm(d)
    com = np.asarray(com_world, dtype=np.float64)
    height = float(n @ (com - np.asarray(support_point, dtype=np.float64)))
    level = max(min(height, settings.max_height_m), settings.radius_m + 0.003)
    centre = com + (level - height) * n
    back = float(np.max(-(np.asarray(vertices_world) - com) @ d))
    start = centre - (back + settings.radius_m + settings.approach_m) * d
    end = centre - (back + settings.radius_m - settings.travel_m) * d
    return PushAction(end_effector=EndEffector(type="sphere", radius_m=settings.radius_m),
                      start=[float(x) for x in start],
                      waypoints=[Waypoint(position=[float(x) for x in end],
                                          speed_mps=settings.speed_mps)],
                      settle_s=settings.settle_s)


def simulate_push(export_dir: Path, action: PushAction, pushed_id: int) -> PushOutcome:
    """Replay ``action`` on ``export_dir`` (PyBullet, the pusher of ``r2s predict``)."""
    client = connect_direct()
    try:
        loaded = load_export_scene(client, export_dir)
        initial = dict(zip(loaded.ids, loaded.initial_world_from_object()))
        final = replay_push(client, loaded, action)
    finally:
        pb.disconnect(physicsClientId=client)
    moved = {}
    for i in loaded.ids:
        com = loaded.com_in_object[i]
        moved[i] = (final[i][:3, :3] @ com + final[i][:3, 3]) - (initial[i][:3, :3] @ com
                                                                  + initial[i][:3, 3])
    turned = float(rotation_angle_deg(initial[pushed_id][:3, :3], final[pushed_id][:3, :3]))
    return PushOutcome(pushed_id, action, final, moved, turned)


def _ball_like(mesh: trimesh.Trimesh) -> bool:
    """Extents within 15 % and most of the bounding sphere filled: it would roll away."""
    ext = np.asarray(mesh.extents)
    r = 0.5 * float(ext.mean())
    filled = abs(float(mesh.volume)) / (4.0 / 3.0 * np.pi * r ** 3)
    return bool(ext.min() > 0.85 * ext.max() and filled > 0.75)


def _turned(v: np.ndarray, n: np.ndarray, deg: float) -> np.ndarray:
    a = np.radians(deg)
    return v * np.cos(a) + np.cross(n, v) * np.sin(a) + n * (n @ v) * (1 - np.cos(a))


def choose_push(paths: ScenePaths, export_dir: Path, settings: PushSettings) -> PushOutcome:
    """The best push (see the module docstring) on the gt exported in ``export_dir``."""
    gt = read_gt_scene(paths.gt_scene)
    extra = gt.model_extra or {}
    stacked = set((extra.get("contacts") or {}).get("stacked_ids", []))
    camera_centre = np.asarray(extra["camera"]["world_from_camera"])[:3, 3]
    n = np.asarray(gt.support.normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    best: Optional[PushOutcome] = None
    for obj in gt.objects:
        if obj.id in stacked or not (obj.model_extra or {}).get("in_input", True):
            continue
        mesh = load_mesh(paths.gt / obj.mesh)
        if _ball_like(mesh):
            continue
        pose = np.asarray(obj.world_from_object, dtype=np.float64)
        verts = np.asarray(mesh.vertices) @ pose[:3, :3].T + pose[:3, 3]
        com = pose[:3, :3] @ np.asarray(obj.com_in_object) + pose[:3, 3]
        away = com - camera_centre
        away = away - (away @ n) * n
        for turn in TURNS_DEG:
            action = plan_push(verts, com, _turned(away, n, turn), gt.support.point, n, settings)
            outcome = simulate_push(export_dir, action, obj.id)
            if outcome.turned_deg > TOPPLED_DEG:
                continue
            if best is None or outcome.score() > best.score():
                best = outcome
    if best is None:
        raise R2SError(f"{paths.root}: no visible object rests on the table to be pushed")
    return best


def _depth_visuals(paths: ScenePaths, final: dict, work: Path) -> tuple[list[Visual], list[int],
                                                                          Visual]:
    """Untextured visuals of every gt object at ``final`` poses, their ids, and the table."""
    gt = read_gt_scene(paths.gt_scene)
    grey = work / "grey.png"
    write_png(grey, np.full((4, 4, 3), 160, np.uint8))
    visuals, ids = [], []
    for obj in gt.objects:
        obj_file = work / f"{obj.id}.obj"
        write_textured_obj(obj_file, appearance.cylindrical_uv(load_mesh(paths.gt / obj.mesh)))
        visuals.append(Visual(obj_file, grey, np.asarray(final[obj.id])))
        ids.append(obj.id)
    box = trimesh.creation.box([3.0, 3.0, 0.02])
    box.apply_translation([0, 0, -0.01])
    box.visual = trimesh.visual.TextureVisuals(uv=np.zeros((len(box.vertices), 2)))
    write_textured_obj(work / "table.obj", box)
    table_pose = np.eye(4)
    table_pose[:3, :3] = plane_rotation(np.asarray(gt.support.normal, dtype=np.float64))
    table_pose[:3, 3] = gt.support.point
    return visuals, ids, Visual(work / "table.obj", grey, table_pose)


def render_after(paths: ScenePaths, final: dict, work: Path) -> tuple[np.ndarray, np.ndarray]:
    """Depth (H, W) metres (NaN = no reading) and masks (H, W) int ids after the push.

    The true camera of gt/ and the renderer, noise level and depth effects of the image
    before; masks hold the ids of input/masks.png (objects left out of input/ stay 0).
    """
    gt = read_gt_scene(paths.gt_scene)
    extra = gt.model_extra or {}
    options = extra["synth"]["options"]
    injected = extra.get("injected_effects") or {}
    K = np.asarray(extra["camera"]["K"], dtype=np.float64)
    true_pose = np.asarray(extra["camera"]["world_from_camera"], dtype=np.float64)
    visuals, ids, table = _depth_visuals(paths, final, work)
    frame = render(visuals, table, K, true_pose, options["width"], options["height"],
                   Lighting(np.array([0.0, 0.0, 1.0]), 0.6, 0.4, 0.0))
    depth = depth_noise.observe_depth(
        frame.depth_m, K, np.random.default_rng([options["seed"], PUSH_NOISE_STREAM]),
        options["noise"], scale=(injected.get("depth_scale") or {}).get("value", 1.0),
        offset_m=(injected.get("depth_offset_m") or {}).get("value", 0.0))
    in_input = {o.id for o in gt.objects if (o.model_extra or {}).get("in_input", True)}
    masks = np.zeros(frame.segment.shape, dtype=np.int32)
    for k, oid in enumerate(ids):
        if oid in in_input:
            masks[frame.segment == k] = oid
    return depth, masks


def _check_synth_scene(paths: ScenePaths) -> None:
    if not paths.gt_scene.is_file():
        raise R2SError(f"{paths.gt_scene}: missing; an observed push is made on the ground truth")
    extra = json.loads(paths.gt_scene.read_text())
    if "synth" not in extra or "camera" not in extra:
        raise R2SError(f"{paths.gt_scene}: not a scene made by r2s synth (no synth/camera record)")


def add_observed_push(scene_dir: Path, settings: PushSettings = PushSettings()) -> dict:
    """Make the push on ``scene_dir/gt`` and write ``input/interaction/`` and ``gt/push.json``.

    An existing ``input/interaction/`` is replaced (atomically). Returns a summary:
    ``pushed_id``, ``displacement_m`` (its COM displacement, m), ``others_max_m``.
    """
    paths = ScenePaths(Path(scene_dir))
    _check_synth_scene(paths)
    _, depth_unit_m = load_camera(paths.camera)
    work = Path(tempfile.mkdtemp(prefix="r2s-push-"))
    try:
        export_dir = export_ground_truth(paths.root, work)
        best = choose_push(paths, export_dir, settings)
        depth, masks = render_after(paths, best.final, work)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    recover_dir(paths.interaction)
    tmp = scratch_dir(paths.interaction)
    atomic_write_json(tmp / paths.push_action.name, best.action.model_dump())
    write_png(tmp / paths.depth_after_png.name, depth_png(depth, depth_unit_m))
    write_png(tmp / paths.masks_after.name,
              masks.astype(np.uint8 if masks.max() < 256 else np.uint16))
    # what the operator knows: which object was aimed at; the motion is measured from
    # the images (r2s.interaction.track), the true one is in gt/push.json
    atomic_write_json(tmp / paths.observed_push.name, {"pushed_id": best.pushed_id,
                                                       "objects": []})
    commit_dir(tmp, paths.interaction)
    atomic_write_json(paths.gt_push, {
        "pushed_id": best.pushed_id, "action": best.action.model_dump(),
        "settings": settings.__dict__,
        "objects": [{"id": int(i), "world_from_object": np.asarray(p).tolist(),
                     "com_displacement_m": [float(x) for x in best.com_displacement_m[i]]}
                    for i, p in sorted(best.final.items())]})
    others = [float(np.linalg.norm(d)) for i, d in best.com_displacement_m.items()
              if i != best.pushed_id]
    return {"pushed_id": best.pushed_id,
            "displacement_m": float(np.linalg.norm(best.com_displacement_m[best.pushed_id])),
            "others_max_m": max(others, default=0.0)}
