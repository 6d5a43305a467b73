"""The ``export`` stage: the reconstructed scene as a simulator-ready ``export/`` folder.

It reads the latest state stage that has run (``source=auto``: texture > physopt > geomopt
> init), or a named one, or the ground truth (``source=gt``, for checking the judge against
the generator). Mass is volume x density where no stage estimated it; COM is the shape's
centre of mass where none was estimated; collision geometry is a convex decomposition.
A state is exported as the scene's model corrects it (COM shifts, friction, a tilted table
kept by ``r2s diagnose --set apply=true``: :func:`r2s.diagnose.model.corrected_state`);
the ground truth is exported as it is.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal, Optional

import numpy as np
from pydantic import Field

from r2s.diagnose.model import corrected_state
from r2s.errors import R2SError, StageError
from r2s.geometry.convex_cache import cached_convex_decomposition
from r2s.geometry.mass_properties import mass_properties
from r2s.io.input_scene import load_camera
from r2s.io.export_writer import ExportBody, write_export
from r2s.io.mesh_io import load_mesh, welded
from r2s.io.paths import ScenePaths
from r2s.io.scene_json import read_gt_scene
from r2s.io.state import read_state
from r2s.physical.provenance import resolve_physics, user_entries
from r2s.stages.base import StageContext, StageOptions, StageSpec
from r2s.stages.manifest import Manifest
from r2s.stages.select import latest_state_stage


class Options(StageOptions):
    source: Literal["auto", "init", "geomopt", "physopt", "texture", "gt"] = Field(
        "auto", description="Which result to export: the latest stage that ran, a named "
                            "stage, or gt (the ground truth, for judging the judge).")
    density_kg_m3: Optional[float] = Field(
        None, gt=0, description="Density where no mass is estimated (unset: by label, "
                                "r2s/physical/density_table.py).")
    default_friction: float = Field(0.8, gt=0, description="Body friction where none is estimated.")
    convex_threshold: float = Field(0.05, gt=0, description="CoACD concavity threshold.")
    max_convex_pieces: int = Field(64, ge=1, description="Most convex pieces per object.")
    restitution: float = Field(0.0, ge=0, le=1, description="Restitution of every body.")


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


def _bodies_from_gt(paths: ScenePaths) -> tuple[list, dict, list[dict]]:
    gt = read_gt_scene(paths.gt_scene)
    items = []
    for obj in gt.objects:
        items.append(dict(id=obj.id, label=obj.label, mesh_path=paths.gt / obj.mesh,
                          pose=np.asarray(obj.world_from_object), mass_kg=obj.mass_kg,
                          com=np.asarray(obj.com_in_object), friction=obj.friction,
                          from_gt=True, extra={"source": "gt"}))
    return gt.gravity, gt.support.model_dump(), items


def _bodies_from_state(paths: ScenePaths, stage: str, model: dict
                       ) -> tuple[list, dict, list[dict]]:
    raw = read_state(paths.stage_dir(stage))
    state = corrected_state(raw, model)
    items = []
    known = set(type(state.objects[0]).model_fields) if state.objects else set()
    for obj in state.objects:
        extra = {k: v for k, v in obj.model_dump().items() if k not in known}
        items.append(dict(id=obj.id, label=obj.label, mesh_path=paths.stage_dir(stage) / obj.mesh,
                          pose=obj.pose, mass_kg=obj.mass_kg,
                          com=None if obj.com_in_object is None else np.asarray(obj.com_in_object),
                          friction=obj.friction, restitution=obj.restitution, stage=stage,
                          provenance=extra.get("provenance"),
                          fitted=_fitted(raw.object(obj.id), obj),
                          extra={"source": obj.source, "stage": stage,
                                 **{k: v for k, v in extra.items() if _scalar(v)}}))
    return state.gravity, state.support.model_dump(), items


def _fitted(before, after) -> list[str]:
    """Values the scene's model (a diagnose fit) changed: "friction", "com"."""
    out = ["friction"] if before.friction != after.friction else []
    return out + (["com"] if before.com_in_object != after.com_in_object else [])


def _scalar(v: object) -> bool:
    return isinstance(v, (int, float, str, bool)) or v is None


def _camera(paths: ScenePaths):
    """The input camera (for the USD and MJCF scenes), or None without input/camera.json."""
    try:
        return load_camera(paths.camera)[0]
    except R2SError:
        return None


def run(ctx: StageContext) -> dict:
    paths, opt = ctx.paths, ctx.options
    source = _resolve_source(paths, opt, ctx.manifest)
    if source == "gt":
        gravity, support, items = _bodies_from_gt(paths)
    else:
        gravity, support, items = _bodies_from_state(paths, source, ctx.manifest.model)
    cache = paths.root / ".cache" / "convex"
    bodies = []
    users = {} if source == "gt" else user_entries(paths.root)
    for k, item in enumerate(items):
        ctx.progress(f"object {item['id']}: convex decomposition", k / max(len(items), 1))
        mesh = load_mesh(item["mesh_path"])
        geom = welded(mesh)
        pieces = cached_convex_decomposition(geom, cache, threshold=opt.convex_threshold,
                                             max_pieces=opt.max_convex_pieces)
        unit = mass_properties(geom, pieces, mass_kg=1.0)
        mass, friction, com, provenance = resolve_physics(
            item, unit.volume_m3, unit.com_in_object, users.get(item["id"]),
            opt.density_kg_m3, opt.default_friction)
        # An estimated COM (non-uniform density) keeps the uniform body's inertia: the
        # inertia of a non-uniform body is not observable from one image.
        inertia = unit.inertia_about_com * mass
        bodies.append(ExportBody(
            id=item["id"], label=item["label"], visual_mesh=mesh, collision_pieces=pieces,
            world_from_object=item["pose"], mass_kg=mass, com_in_object=com,
            inertia_about_com=inertia, friction=friction,
            restitution=item.get("restitution", opt.restitution) or opt.restitution,
            extra={**item["extra"], "provenance": provenance},
        ))
    support.setdefault("friction", opt.default_friction)
    write_export(ctx.out_dir, gravity, support, bodies, camera=_camera(paths))
    ctx.progress("done", 1.0)
    return {"source": source, "objects": len(bodies),
            "collision_pieces": int(sum(len(b.collision_pieces) for b in bodies))}


STAGE = StageSpec("export", Options, inputs, run, uses_model=frozenset({"state"}))
