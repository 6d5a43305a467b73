"""Before/after: rerun the affected stages on a copy of the scene with the effects in the model.

The scene is copied into a temporary folder (stage outputs, manifest, the convex-piece
cache; no scratch folders, no earlier ``diagnose/``). The fitted effects are added to the
copy's ``manifest.model`` (composed with what the model already holds) exactly as
``--set apply=true`` adds them to the scene's, and the pipeline stages that ran in the
original are rerun from the first one an effect affects (init for input-level effects;
physopt, else export, for state-level ones), with the options the original recorded. The
stages apply the model themselves (:mod:`r2s.scene_model`'s hooks), so the copy's
``input/`` and state files are never patched and nothing is applied twice. The original
scene is never written.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import Any, Mapping, Optional

from r2s.console import ProgressFn, silent_progress
from r2s.diagnose.effects import get_effect
from r2s.diagnose.effects.base import EffectFit
from r2s.scene_model import with_effect
from r2s.io.paths import ScenePaths
from r2s.io.manifest import load_manifest, save_manifest
from r2s.runner.base import run_stage
from r2s.runner.pipeline import stage_options
from r2s.runner.registry import PIPELINE, get_stage


def copy_scene(scene_dir: Path, dest_root: Path) -> Path:
    """A working copy of ``scene_dir`` under ``dest_root`` (see the module docstring)."""
    src = Path(scene_dir).resolve()
    dst = Path(dest_root) / src.name
    cache, convex = ScenePaths(src).cache, ScenePaths(src).convex_cache.name

    def ignore(folder: str, names: list[str]) -> set[str]:
        here = Path(folder).resolve()
        skip = {n for n in names if n.startswith(".tmp-") or n.startswith(".old-")}
        if here == src:
            skip |= {n for n in names if n == "diagnose"}
        if here == cache:
            skip |= {n for n in names if n != convex}
        return skip

    shutil.copytree(src, dst, ignore=ignore)
    for p in dst.rglob("*"):  # a read-only source (a shared scene) gives a writable copy
        p.chmod(0o755 if p.is_dir() else 0o644)
    return dst


def stages_to_rerun(scene_dir: Path, fits: list[EffectFit],
                    requested: Optional[list[str]] = None) -> list[str]:
    """Pipeline stages that ran in the scene, from the first one the effects affect."""
    manifest = load_manifest(ScenePaths(Path(scene_dir)).manifest)
    ran = [s for s in PIPELINE
           if (rec := manifest.stages.get(s)) is not None and rec.status == "done"]
    if requested:
        return [s for s in PIPELINE if s in requested]
    levels = {get_effect(f.effect).level for f in fits}
    if "input" in levels:
        first = "init"
    else:
        first = "physopt" if "physopt" in ran else "export"
    return [s for s in PIPELINE[PIPELINE.index(first):] if s in ran]


def rerun_with_effects(scene_dir: Path, fits: list[EffectFit], work_root: Path,
                       stages: Optional[list[str]] = None,
                       progress: ProgressFn = silent_progress) -> tuple[Path, list[str]]:
    """Copy the scene into ``work_root``, put ``fits`` into its model, rerun the stages.

    Returns the copy's path and the stages rerun.
    """
    copy = copy_scene(scene_dir, work_root)
    paths = ScenePaths(copy)
    manifest = load_manifest(paths.manifest)
    manifest.model = model_with_fits(manifest.model, fits)
    save_manifest(paths.manifest, manifest)
    order = stages_to_rerun(scene_dir, fits, stages)
    for k, name in enumerate(order):
        progress(f"rerunning {name} with the effect", k / max(len(order), 1))
        spec = get_stage(name)
        options = stage_options(spec, load_manifest(paths.manifest), {})
        run_stage(spec, copy, options, force=True)
    return copy, order


def model_with_fits(model: Mapping[str, Any] | None, fits: list[EffectFit]) -> dict:
    """``model`` with every fitted effect added (what ``--set apply=true`` records)."""
    new: dict = dict(model or {})
    for fit in fits:
        new = with_effect(new, fit.effect, fit.params)
    return new


def temporary_root() -> tempfile.TemporaryDirectory:
    return tempfile.TemporaryDirectory(prefix="r2s-diagnose-rerun-")
