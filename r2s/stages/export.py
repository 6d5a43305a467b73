"""The ``export`` stage: the reconstructed scene as a simulator-ready ``export/`` folder.

It reads the latest state stage that has run (``source=auto``: texture > physopt > geomopt
> init), or a named one, or the ground truth (``source=gt``, for checking the judge against
the generator). Mass is volume x density where no stage estimated it; COM is the shape's
centre of mass where none was estimated; collision geometry is a convex decomposition.
A state is exported as the scene's model corrects it (COM shifts, friction, a tilted table
kept by ``r2s diagnose --set apply=true``: :func:`r2s.scene_model.corrected_state`);
the ground truth is exported as it is.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field

from r2s.scene_model import corrected_state
from r2s.errors import StageError
from r2s.io.paths import ScenePaths
from r2s.io.state import read_state
from r2s.runner.base import StageContext, StageOptions, StageSpec
from r2s.io.manifest import Manifest
from r2s.io.latest_state import latest_state_stage
from r2s.sim.export_scene import BodyParams, ObjectItem, build_and_write, gt_items


class Options(StageOptions, BodyParams):
    """The body parameters (:class:`r2s.sim.export_scene.BodyParams`) and the source."""

    source: Literal["auto", "init", "geomopt", "physopt", "texture", "gt"] = Field(
        "auto", description="Which result to export: the latest stage that ran, a named "
                            "stage, or gt (the ground truth, for judging the judge).")


def _resolve_source(paths: ScenePaths, options: Options, manifest: Manifest) -> str:
    if options.source == "gt":
        if not paths.gt_scene.is_file():
            raise StageError(f"{paths.gt_scene}: missing; source=gt needs a benchmark scene")
        return "gt"
    return latest_state_stage(paths, manifest, None if options.source == "auto" else options.source)


def inputs(paths: ScenePaths, options: Options, manifest: Manifest) -> list[Path]:
    try:
        source = _resolve_source(paths, options, manifest)
    except StageError:
        return []
    return [paths.gt] if source == "gt" else [paths.stage_dir(source)]


def _bodies_from_state(paths: ScenePaths, stage: str, model: dict
                       ) -> tuple[list, dict, list[ObjectItem]]:
    state = corrected_state(read_state(paths.stage_dir(stage)), model)
    items = []
    known = set(type(state.objects[0]).model_fields) if state.objects else set()
    for obj in state.objects:
        extra = {k: v for k, v in obj.model_dump().items() if k not in known}
        items.append(ObjectItem(
            id=obj.id, label=obj.label, mesh_path=paths.stage_dir(stage) / obj.mesh,
            pose=obj.pose, mass_kg=obj.mass_kg,
            com=None if obj.com_in_object is None else np.asarray(obj.com_in_object),
            friction=obj.friction, restitution=obj.restitution,
            extra={"source": obj.source, "stage": stage,
                   **{k: v for k, v in extra.items() if _scalar(v)}}))
    return state.gravity, state.support.model_dump(), items


def _scalar(v: object) -> bool:
    return isinstance(v, (int, float, str, bool)) or v is None


def run(ctx: StageContext) -> dict:
    paths, opt = ctx.paths, ctx.options
    source = _resolve_source(paths, opt, ctx.manifest)
    if source == "gt":
        gravity, support, items = gt_items(paths)
    else:
        gravity, support, items = _bodies_from_state(paths, source, ctx.manifest.model)
    bodies = build_and_write(ctx.out_dir, gravity, support, items, opt, paths.convex_cache,
                             ctx.progress)
    ctx.progress("done", 1.0)
    return {"source": source, "objects": len(bodies),
            "collision_pieces": int(sum(len(b.collision_pieces) for b in bodies))}


STAGE = StageSpec("export", Options, inputs, run, uses_model=frozenset({"state"}))
