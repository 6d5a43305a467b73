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
from typing import Literal, Optional

import numpy as np
from pydantic import Field

from r2s.geometry.unsegmented import UNSEGMENTED_KEY
from r2s.io.unmodelled import write_unmodelled
from r2s.scene_model import corrected_input, corrected_state
from r2s.errors import InputError, R2SError, StageError
from r2s.io.declared_world import write_declared_world
from r2s.io.input_scene import InputScene, load_camera, load_input
from r2s.io.mesh_io import load_mesh
from r2s.io.paths import PHYSOPT_COLLISION_DIR, ScenePaths
from r2s.io.state import SceneState, read_state
from r2s.metrics.observation import instance_ids
from r2s.metrics.observation_check import (SEEN_TOLERANCE_DEG, SEEN_TOLERANCE_M, FlagTolerances,
                                          check_observation)
from r2s.physopt.observation_bound import OBSERVATION_FLAG_KEY, SEEN_POSE_KEY
from r2s.runner.base import StageContext, StageOptions, StageSpec
from r2s.io.manifest import Manifest
from r2s.io.latest_state import latest_state_stage
from r2s.physical.provenance import user_entries
from r2s.sim.export_scene import BodyParams, ObjectItem, build_and_write, gt_items


class Options(StageOptions, BodyParams):
    """The body parameters (:class:`r2s.sim.export_scene.BodyParams`) and the source."""

    source: Literal["auto", "init", "geomopt", "physopt", "texture", "gt"] = Field(
        "auto", description="Which result to export: the latest stage that ran, a named "
                            "stage, or gt (the ground truth, for judging the judge).")
    observation: bool = Field(True, description="Measure each object against the input view "
                                                "and write its 'observation' block (IoU, UCD, "
                                                "displacement, flag) into scene.json.")
    flag_displacement_m: float = Field(SEEN_TOLERANCE_M, gt=0, description="Flag an object whose mesh "
                                       "centre is farther than this from its init pose, m.")
    flag_displacement_deg: float = Field(SEEN_TOLERANCE_DEG, gt=0, description="... or that turned more "
                                         "than this from its init pose, degrees.")
    flag_min_iou: float = Field(0.5, ge=0, le=1, description="... or whose silhouette IoU is "
                                "below this (masks of at least 1000 px).")
    flag_max_free_space: float = Field(0.5, ge=0, description="... or that fills more space "
                                       "the camera saw empty than this share of its mask.")
    flag_min_iou_kept: float = Field(0.75, ge=0, le=1, description="... or whose silhouette "
                                     "IoU fell below this share of the IoU it has when it "
                                     "alone is put back at its init pose, where it was seen "
                                     "(any mask size; 0 = off).")

    def tolerances(self) -> FlagTolerances:
        return FlagTolerances(self.flag_displacement_m, self.flag_displacement_deg,
                              self.flag_min_iou, self.flag_max_free_space,
                              min_iou_kept=self.flag_min_iou_kept)


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
    found = [paths.gt] if source == "gt" else [paths.stage_dir(source), paths.objects]
    collision = _collision_stage(paths, source)
    if collision:
        found.append(paths.stage_dir(collision))
    if options.observation:
        found += [paths.stage_dir("init"), paths.camera, paths.depth_png, paths.depth_npy,
                  paths.masks]
    return found


def _collision_stage(paths: ScenePaths, source: str) -> str | None:
    """physopt when the exported state is texture's and physopt's state exists: its meshes
    hold the pieces physopt checked (:attr:`ObjectItem.collision_mesh_path`)."""
    if source == "texture" and (paths.stage_dir("physopt") / "state.json").is_file():
        return "physopt"
    return None


def _checked_pieces_file(paths: ScenePaths, stage: str, object_id: int) -> Path | None:
    """physopt's file of the pieces it checked for this object, when physopt is the
    exported stage or texture's collision stage (:func:`_collision_stage`)."""
    if stage != "physopt" and _collision_stage(paths, stage) != "physopt":
        return None
    path = paths.stage_dir("physopt") / PHYSOPT_COLLISION_DIR / f"{object_id}.npz"
    return path if path.is_file() else None


def _bodies_from_state(paths: ScenePaths, stage: str, model: dict
                       ) -> tuple[list, dict, list[ObjectItem]]:
    raw = read_state(paths.stage_dir(stage))
    collision = _collision_stage(paths, stage)
    collision_meshes = {o.id: paths.stage_dir(collision) / o.mesh
                        for o in read_state(paths.stage_dir(collision)).objects} \
        if collision else {}
    state = corrected_state(raw, model)
    items = []
    known = set(type(state.objects[0]).model_fields) if state.objects else set()
    for obj in state.objects:
        extra = {k: v for k, v in obj.model_dump().items() if k not in known}
        items.append(ObjectItem(
            id=obj.id, label=obj.label, mesh_path=paths.stage_dir(stage) / obj.mesh,
            pose=obj.pose, mass_kg=obj.mass_kg,
            com=None if obj.com_in_object is None else np.asarray(obj.com_in_object),
            friction=obj.friction, restitution=obj.restitution, stage=stage,
            provenance=extra.get("provenance"), fitted=_fitted(raw.object(obj.id), obj),
            extra={"source": obj.source, "stage": stage,
                   **{k: v for k, v in extra.items() if _scalar(v) or k == SEEN_POSE_KEY}},
            collision_mesh_path=collision_meshes.get(obj.id),
            collision_pieces_path=_checked_pieces_file(paths, stage, obj.id)))
    return state.gravity, state.support.model_dump(), items


def _fitted(before, after) -> tuple[str, ...]:
    """Values the scene's model (a diagnose fit) changed: "friction", "com"."""
    out = ("friction",) if before.friction != after.friction else ()
    return out + (("com",) if before.com_in_object != after.com_in_object else ())


def _camera(paths: ScenePaths):
    """The input camera (for the USD and MJCF scenes), or None without input/camera.json."""
    try:
        return load_camera(paths.camera)[0]
    except R2SError:
        return None


def _scalar(v: object) -> bool:
    return isinstance(v, (int, float, str, bool)) or v is None


def _corrected_view(paths: ScenePaths, model: dict, required: bool) -> Optional[InputScene]:
    """The input as the scene's model corrects it (its camera is in the state's world), or
    None without input/. An incomplete input/ is an error only where the observation check
    needs it (``required``); otherwise the declared camera stands in (:func:`_camera`)."""
    if not paths.input.is_dir():
        return None
    try:
        return corrected_input(load_input(paths.root), model)
    except InputError:
        if required:
            raise
        return None


def _init_state(paths: ScenePaths) -> Optional[SceneState]:
    """init's state as written (None without it)."""
    if not (paths.stage_dir("init") / "state.json").is_file():
        return None
    return read_state(paths.stage_dir("init"))


def _observation(paths: ScenePaths, items: list[ObjectItem], opt: Options, model: dict,
                 view: InputScene, init: Optional[SceneState], support: Optional[dict] = None
                 ) -> tuple[dict[int, dict], list[str], dict]:
    """Per-object ``observation`` blocks, warning lines and a scene summary against the
    input as the scene's ``model`` corrects it (``view``; ``support``: the support plane's
    ``point`` and ``normal``, for the UCD over the points above the table). Takes the flags
    an earlier stage left in ``item.extra`` (:data:`OBSERVATION_FLAG_KEY`) out of them, and
    flags the objects that may rest on one of the unmasked things ``init`` (its state)
    found."""
    for item in items:  # mask ids reconstructed as pieces of this object (extra key)
        pieces = sorted(f for f, p in view.merged_ids.items() if p == item.id)
        if pieces:
            item.extra["mask_ids"] = [item.id, *pieces]
    init_poses = None
    if init is not None:
        init_poses = {o.id: o.pose for o in corrected_state(init, model).objects}
    earlier = {item.id: str(item.extra[OBSERVATION_FLAG_KEY]) for item in items
               if item.extra.get(OBSERVATION_FLAG_KEY)}
    # objects that may rest on something no mask covers
    for region in getattr(init, UNSEGMENTED_KEY, None) or []:
        why = (f"may rest on an unmasked thing {1000 * region['height_m']:.0f} mm tall "
               "that the twin leaves out")
        for i in region.get("rests_on_it", []):
            earlier[i] = f"{earlier[i]}; {why}" if i in earlier else why
    for item in items:
        item.extra.pop(OBSERVATION_FLAG_KEY, None)
        seen = item.extra.pop(SEEN_POSE_KEY, None)  # physopt swapped in init's completion
        if seen is not None and init_poses is not None:
            init_poses[item.id] = np.asarray(seen, dtype=float)
    meshes = [load_mesh(item.mesh_path) for item in items]
    check = check_observation(
        [m.copy().apply_transform(np.asarray(item.pose)) for m, item in zip(meshes, items)],
        [item.id for item in items], view.camera.K, view.camera.world_from_camera,
        view.depth_m, view.masks, {item.id: np.asarray(item.pose) for item in items},
        init_poses, {item.id: np.asarray(m.centroid) for m, item in zip(meshes, items)},
        opt.tolerances(), earlier, mask_ids=instance_ids(view.masks),
        support=None if support is None else (np.asarray(support["point"], dtype=float),
                                              np.asarray(support["normal"], dtype=float)))
    summary = {k: None if v is None else round(float(v), 4)
               for k, v in check.scene.summary().items()}
    return check.blocks, check.warnings, summary


def run(ctx: StageContext) -> dict:
    paths, opt = ctx.paths, ctx.options
    source = _resolve_source(paths, opt, ctx.manifest)
    if source == "gt":
        gravity, support, items = gt_items(paths)
    else:
        gravity, support, items = _bodies_from_state(paths, source, ctx.manifest.model)
    users = {} if source == "gt" else user_entries(paths.root)
    warnings: list[str] = []
    observed: dict = {}
    init = _init_state(paths)
    view = _corrected_view(paths, ctx.manifest.model, required=opt.observation)
    if opt.observation and view is not None:
        ctx.progress("observation check", 0.0)
        blocks, warnings, observed = _observation(paths, items, opt, ctx.manifest.model, view,
                                                  init, support)
        for item in items:
            if item.id in blocks:
                item.extra["observation"] = blocks[item.id]
    # the ground truth lives in the true world, where the declared camera is the best guess
    camera = view.camera if view is not None and source != "gt" else _camera(paths)
    bodies = build_and_write(ctx.out_dir, gravity, support, items, opt, paths.convex_cache,
                             ctx.progress, users=users, camera=camera)
    if view is not None and source != "gt" and view.corrected_from_declared is not None:
        write_declared_world(ctx.out_dir, view.corrected_from_declared, gravity)
    unsegmented = getattr(init, UNSEGMENTED_KEY, None)
    if source != "gt" and unsegmented:
        write_unmodelled(ctx.out_dir, unsegmented)
    ctx.progress("done", 1.0)
    summary = {"source": source, "objects": len(bodies),
               "collision_pieces": int(sum(len(b.collision_pieces) for b in bodies))}
    if opt.observation:
        summary.update(flagged_objects=sum(bool(b.extra.get("observation", {}).get("flagged"))
                                           for b in bodies),
                       silhouette_iou=observed.get("silhouette_iou"),
                       ucd_mm=observed.get("ucd_mm"),
                       free_space_violation=observed.get("free_space_violation"),
                       warnings=warnings)
    return summary


STAGE = StageSpec("export", Options, inputs, run, uses_model=frozenset({"state", "input"}))
