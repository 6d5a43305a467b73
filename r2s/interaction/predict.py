"""``r2s predict SCENE [--action FILE]``: what the twin says a push will do.

Loads ``export/`` into PyBullet, replays the push (``--action``, else the observed push
``input/interaction/push.json``), and writes ``<scene>/predict/`` (atomically):
``predicted.json`` (final ``world_from_object`` per object and its displacement) and
``before_after.png`` seen from the input camera.

When the replayed push is the observed one, ``predicted.json`` also holds ``error``
(:mod:`r2s.metrics.push_prediction`): the UCD of the observed points after the push
(``input/interaction/depth_after`` inside ``masks_after``) to the predicted meshes, and,
where ``gt/push.json`` holds the true outcome of the same push, the pose error of the
predicted motion per object.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Optional

import numpy as np
import pybullet as pb
from PIL import Image

from r2s.errors import StageError
from r2s.io.push_action import PushAction, read_action
from r2s.interaction.push import replay_push
from r2s.io.atomic import atomic_write_bytes, atomic_write_json, commit_dir, recover_dir, scratch_dir
from r2s.io.declared_world import camera_in_export_world, points_in_export_world
from r2s.io.input_scene import load_camera
from r2s.io.interaction_input import ObservedPush, load_observed_push, read_true_push
from r2s.io.mesh_io import load_mesh
from r2s.io.paths import ScenePaths
from r2s.io.scene_json import read_gt_scene
from r2s.io.scene_lock import scene_lock
from r2s.metrics.geometry import posed
from r2s.metrics.push_prediction import motion_error, observed_points, push_ucd
from r2s.sim.pybullet_bodies import connect_direct
from r2s.sim.pybullet_scene import LoadedScene, load_export_scene
from r2s.sim.render import colour_bodies, render_rgb, scaled_intrinsics, side_by_side


def _frame(client: int, paths: ScenePaths, width_px: int = 640) -> np.ndarray | None:
    if not paths.camera.is_file():
        return None
    cam = camera_in_export_world(load_camera(paths.camera)[0], paths.export)
    scale = min(1.0, width_px / cam.width)
    return render_rgb(client, scaled_intrinsics(cam.K, scale), cam.world_from_camera,
                      max(1, round(cam.width * scale)), max(1, round(cam.height * scale)))


def _action(paths: ScenePaths, action_path: Optional[Path]
            ) -> tuple[PushAction, Optional[ObservedPush]]:
    """The push to replay and, when it is the observed push, the observation."""
    if action_path is None:
        observed = load_observed_push(paths.root)
        if observed is None:
            raise StageError(f"no --action given and no observed push "
                             f"({paths.push_action} is missing)")
        return observed.action, observed
    action = read_action(action_path)
    observed = load_observed_push(paths.root) if paths.push_action.is_file() else None
    return action, observed if observed is not None and observed.action == action else None


def _in_export_world(action: PushAction, paths: ScenePaths) -> PushAction:
    """The push (declared world, as input/interaction/ and --action give it) in the export's
    world, which differs where the declared camera pose was corrected
    (:mod:`r2s.io.declared_world`). A box end effector keeps its axes."""
    declared = np.array([action.start] + [w.position for w in action.waypoints])
    path = points_in_export_world(declared, paths.export)
    waypoints = [w.model_copy(update={"position": p.tolist()})
                 for w, p in zip(action.waypoints, path[1:])]
    return action.model_copy(update={"start": path[0].tolist(), "waypoints": waypoints})


def prediction_error(paths: ScenePaths, loaded: LoadedScene, initial: dict, final: dict,
                     observed: ObservedPush) -> dict:
    """``error`` of predicted.json (see the module docstring); initial / final: id -> (4, 4)."""
    out: dict = {"pushed_id": observed.pushed_id}
    if observed.depth_after_m is not None and observed.masks_after is not None:
        cam = camera_in_export_world(load_camera(paths.camera)[0], paths.export)
        points = observed_points(observed.depth_after_m, observed.masks_after, cam.K,
                                 cam.world_from_camera)
        meshes = {o.id: posed(load_mesh(loaded.export_dir / o.visual_mesh), final[o.id])
                  for o in loaded.scene.objects if o.id in points}
        out.update(push_ucd(points, meshes))
        pushed = [o for o in out["objects"] if o["id"] == observed.pushed_id]
        out["pushed_ucd_mm"] = pushed[0]["ucd_mm"] if pushed else None
    truth = read_true_push(paths.gt_push)
    gt = read_gt_scene(paths.gt_scene)
    if truth is not None and gt is not None and truth.action == observed.action:
        poses = []
        for obj in gt.objects:
            if obj.id not in final or obj.id not in truth.final:
                continue
            t_mm, r_deg = motion_error(initial[obj.id], final[obj.id],
                                       np.asarray(obj.world_from_object), truth.final[obj.id],
                                       np.asarray(obj.com_in_object))
            poses.append({"id": obj.id, "translation_mm": t_mm, "rotation_deg": r_deg})
        out["pose"] = poses
        out["pushed_id"] = truth.pushed_id
        pushed = [p for p in poses if p["id"] == truth.pushed_id]
        out["pushed_translation_mm"] = pushed[0]["translation_mm"] if pushed else None
        out["pushed_rotation_deg"] = pushed[0]["rotation_deg"] if pushed else None
    return out


def predict(scene_dir: Path, action_path: Optional[Path] = None) -> dict:
    """Replay the push on ``export/``; returns the summary written to predicted.json.
    Holds the scene's write lock (:mod:`r2s.io.scene_lock`) while it writes."""
    with scene_lock(Path(scene_dir)):
        return _predict(scene_dir, action_path)


def _predict(scene_dir: Path, action_path: Optional[Path]) -> dict:
    paths = ScenePaths(Path(scene_dir))
    if not paths.export_scene.is_file():
        raise StageError(f"{paths.export_scene} is missing; run 'r2s export' first")
    action, observed = _action(paths, None if action_path is None else Path(action_path))
    out = paths.stage_dir("predict")
    recover_dir(out)
    tmp = scratch_dir(out)
    client = connect_direct()
    try:
        loaded = load_export_scene(client, paths.export)
        colour_bodies(client, loaded.body_ids, loaded.support_body)
        initial = dict(zip(loaded.ids, loaded.initial_world_from_object()))
        before = _frame(client, paths)
        final = replay_push(client, loaded, _in_export_world(action, paths))
        after = _frame(client, paths)
    finally:
        pb.disconnect(physicsClientId=client)
    objects = []
    for oid in loaded.ids:
        moved = float(np.linalg.norm(final[oid][:3, 3] - initial[oid][:3, 3]))
        objects.append({"id": int(oid), "world_from_object": final[oid].tolist(),
                        "displacement_m": moved})
    summary = {"action": action.model_dump(), "objects": objects}
    if observed is not None:
        summary["error"] = prediction_error(paths, loaded, initial, final, observed)
    atomic_write_json(tmp / "predicted.json", summary)
    if before is not None and after is not None:
        caption = f"largest displacement {max(o['displacement_m'] for o in objects) * 1000:.0f} mm"
        if summary.get("error", {}).get("ucd_mm") is not None:
            caption += f"; UCD to the observed points {summary['error']['ucd_mm']:.1f} mm"
        picture = side_by_side([before, after], ["before the push", "predicted after"], caption)
        buf = io.BytesIO()
        Image.fromarray(picture).save(buf, format="PNG")
        atomic_write_bytes(tmp / "before_after.png", buf.getvalue())
    commit_dir(tmp, out)
    return summary
