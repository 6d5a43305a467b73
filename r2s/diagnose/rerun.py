"""Before/after: rerun the affected stages on a copy of the scene with the effects in the model.

The scene is copied into a temporary folder (stage outputs, manifest, the convex-piece
cache; no scratch folders, no earlier ``diagnose/``). In the copy:

- input-level effects (depth bias, camera rotation) are baked into the copy's ``input/``
  (composed with the input-level effects the model already holds, which are then dropped
  from the copy's model so that nothing is applied twice);
- state-level effects (COM, friction, table) are added to the copy's ``manifest.model``
  and applied to every state file already there;

and the pipeline stages that ran in the original are rerun from the first one an effect
affects (init for input-level effects; physopt, else export, for state-level ones), with
the options the original recorded. The original scene is never written.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path
from typing import Any, Mapping, Optional

import numpy as np

from r2s.console import ProgressFn, silent_progress
from r2s.diagnose.effects import get_effect
from r2s.diagnose.effects.base import EffectFit
from r2s.diagnose.model import corrected_input, corrected_state, with_effect, without_levels
from r2s.io.atomic import atomic_write_json
from r2s.io.input_scene import load_input, read_json_file
from r2s.io.paths import STATE_STAGES, ScenePaths
from r2s.io.state import read_state, write_state
from r2s.stages.base import run_stage
from r2s.stages.manifest import load_manifest, save_manifest
from r2s.stages.registry import PIPELINE, available, get_stage


def copy_scene(scene_dir: Path, dest_root: Path) -> Path:
    """A working copy of ``scene_dir`` under ``dest_root`` (see the module docstring)."""
    src = Path(scene_dir).resolve()
    dst = Path(dest_root) / src.name

    def ignore(folder: str, names: list[str]) -> set[str]:
        here = Path(folder).resolve()
        skip = {n for n in names if n.startswith(".tmp-") or n.startswith(".old-")}
        if here == src:
            skip |= {n for n in names if n == "diagnose"}
        if here == src / ".cache":
            skip |= {n for n in names if n != "convex"}
        return skip

    shutil.copytree(src, dst, ignore=ignore)
    for p in dst.rglob("*"):  # a read-only source (a shared scene) gives a writable copy
        p.chmod(0o755 if p.is_dir() else 0o644)
    return dst


def bake_input(scene_dir: Path, model: Mapping[str, Any]) -> None:
    """Write ``input/`` of a (copied) scene as ``model``'s input-level effects correct it."""
    paths = ScenePaths(Path(scene_dir))
    inp = corrected_input(load_input(paths.root), model)
    np.save(paths.depth_npy, np.where(np.isfinite(inp.depth_m), inp.depth_m, 0.0)
            .astype(np.float32))
    paths.depth_png.unlink(missing_ok=True)
    camera = read_json_file(paths.camera)
    camera["world_from_camera"] = np.asarray(inp.camera.world_from_camera).tolist()
    atomic_write_json(paths.camera, camera)
    if paths.objects.is_file():
        data = read_json_file(paths.objects)
        poses = {o.id: o.world_from_prior for o in inp.objects}
        for entry in data.get("objects", []):
            pose = poses.get(entry.get("id"))
            if pose is not None and entry.get("world_from_prior") is not None:
                entry["world_from_prior"] = np.asarray(pose).tolist()
        paths.objects.write_text(json.dumps(data, indent=1))


def patch_states(scene_dir: Path, model: Mapping[str, Any]) -> list[str]:
    """Apply ``model``'s state-level effects to every state file of the scene."""
    paths = ScenePaths(Path(scene_dir))
    done = []
    for stage in STATE_STAGES:
        if paths.state(stage).is_file():
            write_state(paths.stage_dir(stage), corrected_state(read_state(paths.stage_dir(stage)),
                                                                model))
            done.append(stage)
    return done


def stages_to_rerun(scene_dir: Path, fits: list[EffectFit],
                    requested: Optional[list[str]] = None) -> list[str]:
    """Pipeline stages that ran in the scene, from the first one the effects affect."""
    manifest = load_manifest(ScenePaths(Path(scene_dir)).manifest)
    ran = [s for s in PIPELINE
           if (rec := manifest.stages.get(s)) is not None and rec.status == "done"]
    if requested:
        return [s for s in PIPELINE if s in requested and available(s)]
    levels = {get_effect(f.effect).level for f in fits}
    if "input" in levels:
        first = "init"
    else:
        first = "physopt" if "physopt" in ran else "export"
    return [s for s in PIPELINE[PIPELINE.index(first):] if s in ran and available(s)]


def rerun_with_effects(scene_dir: Path, fits: list[EffectFit], work_root: Path,
                       stages: Optional[list[str]] = None,
                       progress: ProgressFn = silent_progress) -> tuple[Path, list[str]]:
    """Copy the scene into ``work_root``, put ``fits`` into its model, rerun the stages.

    Returns the copy's path and the stages rerun.
    """
    copy = copy_scene(scene_dir, work_root)
    paths = ScenePaths(copy)
    manifest = load_manifest(paths.manifest)
    new_model: dict = dict(manifest.model)
    for fit in fits:
        new_model = with_effect(new_model, fit.effect, fit.params)
    if any(get_effect(f.effect).level == "input" for f in fits):
        bake_input(copy, new_model)
        new_model = without_levels(new_model, "input")
    manifest.model = new_model
    save_manifest(paths.manifest, manifest)
    patch_states(copy, new_model)
    order = stages_to_rerun(scene_dir, fits, stages)
    for k, name in enumerate(order):
        progress(f"rerunning {name} with the effect", k / max(len(order), 1))
        spec = get_stage(name)
        rec = load_manifest(paths.manifest).stages.get(name)
        options = _options(spec, rec.options if rec is not None else None)
        run_stage(spec, copy, options, force=True)
        if name in STATE_STAGES:  # stages that do not call the hooks yet still get them
            patch_states(copy, new_model)
    return copy, order


def _options(spec, recorded: Optional[dict]):
    from r2s.pipeline import build_options
    from r2s.errors import R2SError

    try:
        return build_options(spec, recorded, {})
    except R2SError:
        return build_options(spec, None, {})


def temporary_root() -> tempfile.TemporaryDirectory:
    return tempfile.TemporaryDirectory(prefix="r2s-diagnose-rerun-")
