"""``r2s predict SCENE --action FILE``: what the twin says a push will do.

Loads ``export/`` into PyBullet, replays the push, and writes ``<scene>/predict/``
(atomically): ``predicted.json`` (final ``world_from_object`` per object and its
displacement) and ``before_after.png`` seen from the input camera.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pybullet as pb
from PIL import Image

from r2s.errors import StageError
from r2s.interaction.action import read_action
from r2s.interaction.push import replay_push
from r2s.io.atomic import atomic_write_bytes, atomic_write_json, commit_dir, recover_dir, scratch_dir
from r2s.io.input_scene import load_camera
from r2s.io.paths import ScenePaths
from r2s.sim.pybullet_bodies import connect_direct
from r2s.sim.pybullet_scene import load_export_scene
from r2s.sim.render import colour_bodies, render_rgb, scaled_intrinsics, side_by_side


def _frame(client: int, paths: ScenePaths, width_px: int = 640) -> np.ndarray | None:
    if not paths.camera.is_file():
        return None
    cam, _ = load_camera(paths.camera)
    scale = min(1.0, width_px / cam.width)
    return render_rgb(client, scaled_intrinsics(cam.K, scale), cam.world_from_camera,
                      max(1, round(cam.width * scale)), max(1, round(cam.height * scale)))


def predict(scene_dir: Path, action_path: Path) -> dict:
    """Replay the action on ``export/``; returns the summary written to predicted.json."""
    paths = ScenePaths(Path(scene_dir))
    if not paths.export_scene.is_file():
        raise StageError(f"{paths.export_scene} is missing; run 'r2s export' first")
    action = read_action(action_path)
    out = paths.stage_dir("predict")
    recover_dir(out)
    tmp = scratch_dir(out)
    client = connect_direct()
    try:
        loaded = load_export_scene(client, paths.export)
        colour_bodies(client, loaded.body_ids, loaded.support_body)
        before_poses = loaded.initial_world_from_object()
        before = _frame(client, paths)
        final = replay_push(client, loaded, action)
        after = _frame(client, paths)
    finally:
        pb.disconnect(physicsClientId=client)
    objects = []
    for k, oid in enumerate(loaded.ids):
        moved = float(np.linalg.norm(final[oid][:3, 3] - before_poses[k][:3, 3]))
        objects.append({"id": int(oid), "world_from_object": final[oid].tolist(),
                        "displacement_m": moved})
    summary = {"action": action.model_dump(), "objects": objects}
    atomic_write_json(tmp / "predicted.json", summary)
    if before is not None and after is not None:
        picture = side_by_side([before, after], ["before the push", "predicted after"],
                               f"largest displacement {max(o['displacement_m'] for o in objects) * 1000:.0f} mm")
        buf = io.BytesIO()
        Image.fromarray(picture).save(buf, format="PNG")
        atomic_write_bytes(tmp / "before_after.png", buf.getvalue())
    commit_dir(tmp, out)
    return summary
