"""Read what diagnose needs from a scene folder and measure its residuals.

The one module of :mod:`r2s.diagnose` that reads a scene directory (the stage's ``run``
and the before/after rerun call it); everything it calls works on loaded data.

- registration and depth residuals: the ``init`` state (the fit to the observation);
- physical residual: the latest *geometric* state (``geomopt``, else ``init``), before
  physopt has tuned physics to hide it, with the model's state-level effects applied;
- support residual: a plane fitted afresh to the table pixels of ``input/``;
- interaction residual: ``input/interaction/push.json`` when present.

Everything is measured on the input as the scene's model corrects it
(:func:`r2s.scene_model.corrected_input`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping, Optional

import numpy as np

from r2s.console import ProgressFn, silent_progress
from r2s.diagnose.data import Residuals, SupportData
from r2s.diagnose.measure.gt_errors import export_gt_errors, metrics_subset, state_gt_errors
from r2s.diagnose.measure.interaction import read_push
from r2s.diagnose.measure.observe import (ObjectModel, depth_residual_map,
                                          interaction_residual, measure_fit_qualities,
                                          physics_residual, registration_residual,
                                          support_residual, table_shape_residual, world_spec)
from r2s.scene_model import corrected_input, corrected_state, model_effects
from r2s.errors import StageError
from r2s.interaction.track import track_objects
from r2s.io.input_scene import InputScene, load_input, read_json_file
from r2s.io.interaction_input import load_observed_push
from r2s.io.mesh_io import load_mesh
from r2s.io.paths import INIT_REPLACED_PRIORS_DIR, ScenePaths
from r2s.io.scene_json import read_export_scene, read_gt_scene
from r2s.metrics.push_prediction import observed_points
from r2s.io.state import SceneState, read_state
from r2s.io.latest_state import GEOMETRY_STAGES, finished, latest_state_stage
from r2s.io.manifest import load_manifest
from r2s.io.recorded_options import recorded_options
from r2s.sim.export_scene import BodyParams

PUSH_FILE = "push.json"


@dataclass(frozen=True)
class MeasureSettings:
    """Noise levels and choices of the measurement (the stage's options)."""

    scale_sigma: float = 0.01
    prior_scale_sigma: float = 0.025
    prior_scale_dof: float = 20.0
    support_sigma_deg: float = 0.3
    table_shape_sigma_m: float = 0.001
    table_height: str = "auto"
    table_height_sigma_m: float = 0.002
    min_fitness: float = 0.6
    min_prior_points: int = 150
    max_rmse_m: float = 0.004
    physics_source: str = "auto"
    com_from_rollout: bool = False
    """Apply a COM offset fitted to an object that rocks in the rollout of the scene's
    state (else it is only reported: see ``PhysicsData.density_evidence``)."""
    physics: bool = True
    horizon_s: float = 1.0
    sigma_translation_m: float = 0.015
    sigma_rotation_deg: float = 5.0
    cap: float = 4.0
    interaction_sigma_m: float = 0.005
    interaction_source: str = "auto"
    """State the observed push is simulated on: auto = the physical residual's (the observed
    geometry, with the default frictions) when the objects the push moved rest in its
    rollout; else physopt's when it ran (solved to rest, with the frictions physopt raised
    or lowered to hold it there), else the physical residual's anyway."""
    density_kg_m3: Optional[float] = None
    default_friction: Optional[float] = None
    """None: the export stage's (recorded, else default) options, so that diagnose rolls
    out the bodies the judge would see."""


@dataclass
class Measured:
    """Residuals of one scene and what they were measured on."""

    residuals: Residuals
    physics_stage: Optional[str]
    qualities: dict = field(default_factory=dict)
    input_scene: Optional[InputScene] = None
    keep: list = field(default_factory=list)  # temporary folders that must outlive residuals


def physics_stage(paths: ScenePaths, source: str) -> str:
    """The state the rollout uses: ``source``, or the latest current of geomopt / init
    for ``auto`` (before physopt has tuned physics to hide the residual)."""
    return latest_state_stage(paths, load_manifest(paths.manifest), source,
                              candidates=("init", "geomopt"))


def tracked_motion(paths: ScenePaths, model: Optional[Mapping[str, Any]],
                   init_state: SceneState, init_objects: list[ObjectModel],
                   inp: InputScene) -> tuple[dict, dict]:
    """``({id: (3,) COM displacement}, {id: tilt of its up direction, rad})`` measured from
    ``input/interaction/``'s images after the push against the image before
    (:mod:`r2s.interaction.track`), both corrected by the model's input-level effects;
    empty when the images after are not given."""
    after = load_observed_push(paths.root)
    if after is None or after.depth_after_m is None or after.masks_after is None:
        return {}, {}
    raw = load_input(paths.root)
    seen = corrected_input(replace(raw, depth_m=after.depth_after_m, masks=after.masks_after),
                           model)
    cam = inp.camera
    before = observed_points(inp.depth_m, inp.masks, cam.K, cam.world_from_camera)
    points_after = observed_points(seen.depth_m, seen.masks, seen.camera.K,
                                   seen.camera.world_from_camera)
    meshes = {o.id: o.mesh for o in init_objects}
    poses = {o.id: np.asarray(o.world_from_object) for o in init_objects}
    coms = {o.id: (o.com_in_object if o.com_in_object is not None else o.mesh.center_mass)
            for o in init_objects}
    tracked = track_objects(meshes, poses, coms, before, points_after,
                            cam.world_from_camera[:3, 3], np.asarray(init_state.support.normal))
    up = np.asarray(init_state.support.normal, dtype=np.float64)
    up = up / np.linalg.norm(up)
    turned = {}
    for i, t in tracked.items():
        rel = t.world_from_object_after[:3, :3] @ poses[i][:3, :3].T
        turned[i] = float(np.arccos(np.clip(up @ rel @ up, -1.0, 1.0)))
    return {i: t.displacement_m for i, t in tracked.items()}, turned


def interaction_stage(paths: ScenePaths, source: str, physics_stage_name: str,
                      struck_at_rest: bool = True) -> str:
    """The state the observed push is simulated on (see ``MeasureSettings``);
    ``struck_at_rest``: the objects the push moved rest in the physical residual's
    rollout."""
    manifest = load_manifest(paths.manifest)
    if source == "auto":
        if struck_at_rest or not finished(paths, manifest, "physopt"):
            return physics_stage_name
        return "physopt"
    return latest_state_stage(paths, manifest, source)


def struck_objects_rest(observed_m: dict, physics, sigma_m: float) -> bool:
    """Do the objects an observed push moved (by more than two noise levels; ``observed_m``:
    id -> (3,) displacement, m) rest in the rollout of ``physics`` (a PhysicsData)?"""
    moved = {i for i, d in observed_m.items() if np.linalg.norm(d) > 2.0 * sigma_m}
    return not (moved & set(physics.moving(physics.motion)))


def export_options(paths: ScenePaths) -> BodyParams:
    """The export stage's body parameters as recorded in the manifest, else its defaults."""
    return recorded_options(load_manifest(paths.manifest), "export", BodyParams)


def prior_areas(inp: InputScene) -> dict[int, float]:
    """id -> surface area (m^2) of each object's metric prior in ``input/``."""
    return {spec.id: float(load_mesh(spec.prior_mesh).area) for spec in inp.objects
            if spec.prior_mesh is not None}


def load_objects(paths: ScenePaths, stage: str, state: SceneState, inp: InputScene
                 ) -> list[ObjectModel]:
    """The state's objects with meshes, and their metric priors' areas."""
    priors = prior_areas(inp)
    out = []
    for obj in state.objects:
        mesh = load_mesh(paths.stage_dir(stage) / obj.mesh)
        from_prior = obj.source in ("prior", None, "")
        out.append(ObjectModel(
            id=obj.id, label=obj.label, mesh=mesh, world_from_object=obj.pose,
            prior_area_m2=priors.get(obj.id) if from_prior else None, mass_kg=obj.mass_kg,
            com_in_object=None if obj.com_in_object is None else np.asarray(obj.com_in_object),
            friction=obj.friction))
    return out


def registration_objects(paths: ScenePaths, objects: list[ObjectModel], inp: InputScene
                         ) -> list[ObjectModel]:
    """``objects`` (init's) for the registration block, each one whose metric prior init
    replaced by its completion (``init/replaced_priors/``) as that registered prior: the
    choice of shape says which fits the view better, not that the prior stopped being
    metric. A depth read 25 % long makes every prior fit worse than its completion, and
    with no prior left to measure, the depth scale was not identifiable at all."""
    folder = paths.stage_dir("init") / INIT_REPLACED_PRIORS_DIR
    if not (folder / "state.json").is_file():
        return objects
    areas = prior_areas(inp)
    replaced = {o.id: o for o in read_state(folder).objects if o.id in areas}
    out = []
    for obj in objects:
        r = replaced.get(obj.id)
        out.append(obj if r is None else replace(
            obj, mesh=load_mesh(folder / r.mesh), world_from_object=r.pose,
            prior_area_m2=areas[obj.id]))
    return out


def model_support(inp: InputScene, gravity: np.ndarray, settings: MeasureSettings,
                  model: Optional[Mapping[str, Any]]) -> Optional[SupportData]:
    """The support residual against the model's table: level under ``gravity``, or the
    normal of a kept ``table_tilt``."""
    support = support_residual(inp, gravity, float(np.radians(settings.support_sigma_deg)),
                               height_sigma_m=settings.table_height_sigma_m,
                               table_height=settings.table_height)
    tilt = model_effects(model).get("table_tilt")
    if support is not None and tilt is not None and "normal_world" in tilt:
        support = replace(support, model_normal=np.asarray(tilt["normal_world"], dtype=float))
    return support


def measure_scene(scene_dir: Path, settings: MeasureSettings,
                  model: Optional[Mapping[str, Any]] = None,
                  progress: ProgressFn = silent_progress) -> Measured:
    """Every residual group of the scene under ``model`` (default: the manifest's)."""
    paths = ScenePaths(Path(scene_dir))
    if model is None:
        model = load_manifest(paths.manifest).model
    if not finished(paths, load_manifest(paths.manifest), "init"):
        raise StageError(f"{paths.root}: diagnose needs the 'init' stage; run 'r2s init' first")
    inp = corrected_input(load_input(paths.root), model)
    init_state = read_state(paths.stage_dir("init"))
    init_objects = load_objects(paths, "init", init_state, inp)

    progress("registration residual", 0.05)
    qualities = measure_fit_qualities(inp, registration_objects(paths, init_objects, inp),
                                      lambda m, f: progress(m, 0.05 + 0.35 * f))
    registration = registration_residual(qualities, settings.scale_sigma, settings.min_fitness,
                                         settings.prior_scale_sigma, settings.prior_scale_dof,
                                         settings.min_prior_points)
    gravity = np.asarray(init_state.gravity, dtype=np.float64)
    support = model_support(inp, gravity, settings, model)
    progress("depth residual", 0.42)
    depth_map = depth_residual_map(inp, init_objects, support)

    physics = interaction = None
    stage = None
    keep: list = []
    notes: list[str] = []
    if settings.physics:
        stage = physics_stage(paths, settings.physics_source)
        progress(f"rollout of the {stage} state", 0.5)
        state = corrected_state(read_state(paths.stage_dir(stage)), model)
        objects = load_objects(paths, stage, state, inp)
        ex = export_options(paths)

        def spec_of(state: SceneState, objects: list[ObjectModel]):
            return world_spec(objects, state.support.point, state.support.normal,
                              state.support.friction, paths.convex_cache,
                              settings.density_kg_m3 or ex.density_kg_m3,
                              settings.default_friction or ex.default_friction, ex.convex)

        spec = spec_of(state, objects)
        keep.append(spec)
        ok = {i: (q.fitness >= settings.min_fitness
                  and (not np.isfinite(q.rmse_m) or q.rmse_m <= settings.max_rmse_m))
              for i, q in qualities.items()}
        physics = physics_residual(spec, np.asarray(state.gravity, dtype=np.float64), ok,
                                   settings.horizon_s, settings.sigma_translation_m,
                                   float(np.radians(settings.sigma_rotation_deg)), settings.cap)
        physics = replace(physics, stage=stage, density_evidence=settings.com_from_rollout)
        push_path = paths.interaction / PUSH_FILE
        if push_path.is_file():
            progress("simulating the observed push", 0.8)
            push, observed = read_push(push_path)
            turned: dict = {}
            if not observed:
                observed, turned = tracked_motion(paths, model, init_state, init_objects, inp)
                if not observed:
                    notes.append(f"{paths.interaction}: no observed.json displacements and "
                                 "no object could be tracked in depth_after/masks_after")
            push_stage = interaction_stage(
                paths, settings.interaction_source, stage,
                struck_objects_rest(observed, physics, settings.interaction_sigma_m))
            push_spec = spec
            if push_stage != stage:
                push_state = corrected_state(read_state(paths.stage_dir(push_stage)), model)
                push_spec = spec_of(push_state, load_objects(paths, push_stage, push_state, inp))
                keep.append(push_spec)
            interaction = interaction_residual(
                push_spec, physics.base, push, observed, settings.interaction_sigma_m,
                rest=physics if push_stage != stage else None, stage=push_stage,
                observed_tilt_rad=turned)
        elif paths.interaction.is_dir():
            notes.append(f"{paths.interaction}: no {PUSH_FILE}; the interaction is not used")
    residuals = Residuals(registration=registration, support=support, physics=physics,
                          interaction=interaction, depth_map=depth_map, notes=tuple(notes),
                          table_shape=table_shape_residual(inp, settings.table_shape_sigma_m,
                                                           support=support))
    return Measured(residuals, stage, qualities, inp, keep)


def _centroid(mesh_path: Path, world_from_object: np.ndarray) -> np.ndarray:
    mesh = load_mesh(mesh_path)
    return np.asarray(world_from_object)[:3, :3] @ mesh.centroid + np.asarray(world_from_object)[:3, 3]


def _latest_geometry_stage(paths: ScenePaths) -> Optional[str]:
    try:
        return latest_state_stage(paths, load_manifest(paths.manifest),
                                  candidates=GEOMETRY_STAGES)
    except StageError:
        return None


def scene_gt_errors(scene_dir: Path) -> Optional[dict]:
    """Ground-truth errors of the scene's export and judge metrics; None without gt/."""
    paths = ScenePaths(Path(scene_dir))
    gt = read_gt_scene(paths.gt_scene)
    if gt is None:
        return None
    out: dict[str, Any] = {}
    metrics = read_json_file(paths.metrics) if paths.metrics.is_file() else None
    out.update(metrics_subset(metrics))
    if paths.export_scene.is_file():
        out.update(export_gt_errors(read_export_scene(paths.export_scene), gt))
    stage = _latest_geometry_stage(paths)
    if stage is not None:
        state = read_state(paths.stage_dir(stage))
        mine = {o.id: _centroid(paths.stage_dir(stage) / o.mesh, o.pose) for o in state.objects}
        truth = {o.id: _centroid(paths.gt / o.mesh, np.asarray(o.world_from_object))
                 for o in gt.objects}
        out.update(state_gt_errors(mine, np.asarray(state.support.normal), gt, truth))
        out["state_stage"] = stage
    out["injected_effects"] = (gt.model_extra or {}).get("injected_effects")
    return out
