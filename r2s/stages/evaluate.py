"""Stage ``evaluate``: judge ``export/`` in PyBullet (and against ``gt/`` where it exists).

Reads only what an outside tool would: ``export/`` (SCENE_FORMAT.md), ``gt/`` and
``input/camera.json`` (for the picture; a camera rotation kept in the scene's model by
``r2s diagnose --set apply=true`` corrects it, as it did init's). Writes ``evaluate/metrics.json`` and
``evaluate/rollout.png`` (first and last frame of the rollout seen by the input camera; the
objects that moved are outlined, with arrows and their displacement, see
:mod:`r2s.pictures.rollout_picture`).

Scene-level keys of metrics.json: ``stability_ratio``, ``settling_time_s``,
``mean_linear_speed_mps``, ``mean_angular_speed_radps`` (rollout under gravity),
``max_penetration_mm``, ``mean_penetration_mm``, ``floating_objects`` (before the rollout),
``chamfer_mm``, ``fscore``, ``fscore_threshold_mm``, ``iou``, ``centroid_error_mm``,
``rotation_error_deg`` (means over the objects matched by id with gt; null without gt;
the rotation error only over objects whose export entry says ``"source": "prior"``),
observation consistency with or without gt (:mod:`r2s.metrics.observation`):
``silhouette_iou`` (pooled), ``min_silhouette_iou`` (worst object with >= 1000 mask px),
``free_space_violation`` (mean over objects), ``ucd_mm`` (mean), ``ucd_above_support_mm``
(mean of the same over the observed points above the table's level; per object also
``support_level_share``, the share of its points at that level), ``max_displacement_m`` /
``max_displacement_deg`` (from init, as export's ``observation`` blocks say) and
``flagged_objects``, plus ``objects`` (the same per object) and ``options``.
``evaluate/observation.png`` shows the rendered silhouettes over the input image, their
free-space violations in red.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Optional

import numpy as np
import pybullet as pb
from PIL import Image
from pydantic import Field

from r2s.forked_map import forked_map
from r2s.console import ProgressFn
from r2s.scene_model import corrected_camera, corrected_input
from r2s.errors import R2SError, StageError
from r2s.io.atomic import atomic_write_bytes, atomic_write_json
from r2s.io.input_scene import load_camera, load_input, load_masks, load_rgb
from r2s.io.mesh_io import load_mesh
from r2s.io.paths import METRICS_FILE, ScenePaths
from r2s.io.scene_json import ExportObject, GtScene, read_gt_scene
from r2s.metrics.geometry import (centroid_error_mm, posed, rotation_error_deg, surface_metrics,
                                  volumetric_iou)
from r2s.metrics.observation import (SceneObservation, instance_ids, observation_picture,
                                     observe_scene, picture_colour)
from r2s.metrics.penetration import (PYBULLET_MESH_MARGIN_M, SUPPORT_ID, PenetrationMetrics,
                                     penetration_metrics, scene_distances)
from r2s.metrics.rendering import render_scene_rgb, rendering_metrics, side_by_side_png
from r2s.metrics.motion import object_motions
from r2s.metrics.stability import object_stability, scene_stability
from r2s.pictures.rollout_picture import Frame, rollout_picture
from r2s.sim.pybullet_bodies import connect_direct
from r2s.sim.pybullet_scene import LoadedScene, load_export_scene
from r2s.sim.render import colour_bodies, render, scaled_intrinsics
from r2s.sim.rollout import Trajectory, rollout
from r2s.runner.base import StageContext, StageOptions, StageSpec
from r2s.io.manifest import Manifest

SCENE_KEYS: tuple[str, ...] = (
    "stability_ratio", "settling_time_s", "mean_linear_speed_mps", "mean_angular_speed_radps",
    "max_penetration_mm", "mean_penetration_mm", "floating_objects",
    "chamfer_mm", "fscore", "fscore_threshold_mm", "iou", "centroid_error_mm",
    "rotation_error_deg", "mass_rel_error", "psnr", "ssim", "lpips",
    "silhouette_iou", "min_silhouette_iou", "free_space_violation", "ucd_mm",
    "ucd_above_support_mm", "max_displacement_m", "max_displacement_deg", "flagged_objects",
    "missing_objects",
)
"""Scene-level keys of metrics.json (and of the stage summary)."""

GEOMETRY_KEYS: tuple[str, ...] = ("chamfer_mm", "fscore", "iou", "centroid_error_mm",
                                  "rotation_error_deg", "mass_rel_error")
"""Per-object metrics against gt/ (scene value: their mean); ``mass_rel_error`` is
|mass - gt mass| / gt mass."""


class Options(StageOptions):
    duration_s: float = Field(3.0, gt=0, description="Rollout length under gravity, seconds.")
    rate_hz: float = Field(240.0, gt=0, description="PyBullet step rate, Hz.")
    record_hz: float = Field(60.0, gt=0,
                             description="Trajectory sampling rate for the metrics, Hz.")
    stable_translation_m: float = Field(
        0.05, gt=0, description="An object is stable if its COM moves less than this, metres.")
    stable_rotation_deg: float = Field(
        5.0, gt=0, description="... and it turns less than this, degrees.")
    floating_gap_mm: float = Field(
        2.0, ge=0, description="An object farther than this from every other body floats, mm.")
    fscore_threshold_mm: float = Field(10.0, gt=0, description="F-score distance threshold, mm.")
    geometry_samples: int = Field(
        10000, ge=100, description="Surface / volume samples per object for CD, F-score, IoU.")
    seed: int = Field(0, description="Seed of the geometry sampling.")
    render: bool = Field(True, description="Write rollout.png (first and last frame).")
    engine: Literal["pybullet", "mujoco"] = Field(
        "pybullet", description="Engine that judges stability (mujoco uses export/scene.xml; "
                                "penetration and pictures always come from PyBullet).")
    render_width_px: int = Field(
        640, ge=32, description="Width of each frame of rollout.png (the camera image is scaled).")


def inputs(paths: ScenePaths, options: Options, manifest: Manifest) -> list[Path]:  # noqa: ARG001
    return [paths.export, paths.gt, paths.camera, paths.rgb, paths.masks, paths.depth_png,
            paths.depth_npy, paths.objects]


def _rendering(paths: ScenePaths, export_objects: list, model: dict
               ) -> tuple[dict, Optional[tuple]]:
    """Rendering metrics of export/ at the input view, and (observed, rendered, object mask)."""
    if not (paths.camera.is_file() and paths.rgb.is_file() and paths.masks.is_file()):
        return ({"psnr": None, "ssim": None, "lpips": None,
                 "lpips_reason": "no input view (input/rgb.png, masks.png, camera.json)"}, None)
    cam = corrected_camera(load_camera(paths.camera)[0], model)
    observed = load_rgb(paths.rgb, cam.width, cam.height)
    object_mask = load_masks(paths.masks, cam.width, cam.height) > 0
    meshes = [load_mesh(paths.export / o.visual_mesh).apply_transform(np.asarray(o.world_from_object))
              for o in export_objects]
    rendered, _ = render_scene_rgb(meshes, cam, ids=[o.id for o in export_objects])
    return rendering_metrics(observed, rendered, object_mask), (observed, rendered, object_mask)


def _observation(paths: ScenePaths, export_objects: list, model: dict, support=None
                 ) -> tuple[Optional[SceneObservation], Optional[np.ndarray], str]:
    """Observation metrics of export/ against the input view, the picture, or why not
    (``support``: the export's support plane, with ``point`` and ``normal``, for the UCD
    over the points above the table)."""
    try:
        view = corrected_input(load_input(paths.root), model)
    except R2SError as exc:
        return None, None, f"no input view: {exc}"
    meshes = [load_mesh(paths.export / o.visual_mesh).apply_transform(np.asarray(o.world_from_object))
              for o in export_objects]
    ids = [o.id for o in export_objects]
    scene = observe_scene(meshes, ids, view.camera.K, view.camera.world_from_camera,
                          view.depth_m, view.masks, mask_ids=instance_ids(view.masks),
                          support=None if support is None else
                          (np.asarray(support.point, dtype=float),
                           np.asarray(support.normal, dtype=float)))
    for entry, o in zip(scene.objects, export_objects):  # displacement as export measured it
        block = (o.model_extra or {}).get("observation") or {}
        entry.displacement_m = block.get("displacement_m")
        entry.displacement_deg = block.get("displacement_deg")
    summary = scene.summary()
    caption = (f"silhouette IoU {_fmt_or_dash(summary['silhouette_iou'])}  |  free-space "
               f"violation {_fmt_or_dash(summary['free_space_violation'])} (red)  |  UCD "
               f"{_fmt_or_dash(summary['ucd_mm'], 1)} mm")
    picture = observation_picture(view.rgb, scene.rendered.ids, scene.violation_map, view.masks,
                                  {i: picture_colour(i) for i in ids}, caption)
    return scene, picture, ""


def _add_observation(objects: list[dict], export_objects: list,
                     observed: Optional[SceneObservation]) -> dict:
    """Add the observation metrics to each object's entry; return the scene-level ones."""
    flags = [bool(((o.model_extra or {}).get("observation") or {}).get("flagged"))
             for o in export_objects]
    for k, (entry, flagged) in enumerate(zip(objects, flags)):
        per = observed.objects[k] if observed is not None else None
        entry.update({key: None if per is None else getattr(per, attr) for key, attr in (
            ("silhouette_iou", "iou"), ("ucd_mm", "ucd_mm"),
            ("ucd_above_support_mm", "ucd_above_support_mm"),
            ("support_level_share", "support_level_share"),
            ("free_space_violation", "free_space_violation"), ("free_space_px", "free_space_px"),
            ("mask_px", "mask_px"), ("displacement_m", "displacement_m"),
            ("displacement_deg", "displacement_deg"))})
        entry["flagged"] = flagged
    scene = observed.summary() if observed is not None else {
        k: None for k in ("silhouette_iou", "min_silhouette_iou", "free_space_violation",
                          "ucd_mm", "ucd_above_support_mm", "max_displacement_m",
                          "max_displacement_deg",
                          "missing_objects")}
    scene["flagged_objects"] = sum(flags)
    return scene


def _fmt_or_dash(value: Optional[float], digits: int = 3) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


# ---- pieces of run() -------------------------------------------------------------------


def _mean_or_none(values: list[Optional[float]]) -> Optional[float]:
    vals = [v for v in values if v is not None and np.isfinite(v)]
    return float(np.mean(vals)) if vals else None


def _finite_or_none(value: Any) -> Any:
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def _source(obj: ExportObject) -> Optional[str]:
    return (obj.model_extra or {}).get("source")


def _geometry_of(paths: ScenePaths, obj: ExportObject, gt: GtScene, options: Options) -> dict:
    """Geometry metrics of one export object against the gt object of the same id."""
    empty: dict[str, Any] = {k: None for k in GEOMETRY_KEYS}
    gt_obj = next((g for g in gt.objects if g.id == obj.id), None)
    if gt_obj is None:
        return empty
    recon = posed(load_mesh(paths.export / obj.visual_mesh), np.asarray(obj.world_from_object))
    truth = posed(load_mesh(paths.gt / gt_obj.mesh), np.asarray(gt_obj.world_from_object))
    surf = surface_metrics(recon, truth, options.fscore_threshold_mm, options.geometry_samples,
                           options.seed)
    rot = None
    if _source(obj) == "prior":
        rot = rotation_error_deg(obj.world_from_object, gt_obj.world_from_object)
    return {
        "chamfer_mm": surf.chamfer_mm, "fscore": surf.fscore,
        "precision": surf.precision, "recall": surf.recall,
        "iou": volumetric_iou(recon, truth, options.geometry_samples, options.seed),
        "centroid_error_mm": centroid_error_mm(recon, truth),
        "rotation_error_deg": rot,
        "mass_rel_error": abs(float(obj.mass_kg) - float(gt_obj.mass_kg)) / float(gt_obj.mass_kg),
    }


def _geometry_per_object(paths: ScenePaths, objects: list[ExportObject],
                         gt: Optional[GtScene], options: Options) -> list[dict]:
    """:func:`_geometry_of` for each object (all None without gt/); the objects' metrics
    are independent (seeded samples), so they are computed side by side on the cores."""
    if gt is None:
        return [{key: None for key in GEOMETRY_KEYS} for _ in objects]
    return forked_map(lambda obj: _geometry_of(paths, obj, gt, options), objects)


def _camera(paths: ScenePaths, loaded: LoadedScene, model: dict
            ) -> tuple[np.ndarray, np.ndarray, int, int]:
    """(K, world_from_camera, width, height): the input camera, else a view of the objects."""
    if paths.camera.is_file():
        cam = corrected_camera(load_camera(paths.camera)[0], model)
        return cam.K, cam.world_from_camera, cam.width, cam.height
    poses = loaded.initial_world_from_object()
    target = poses[:, :3, 3].mean(axis=0) if len(poses) else np.zeros(3)
    eye = target + np.array([0.6, -0.6, 0.6])
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    world_from_camera = np.eye(4)
    world_from_camera[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    world_from_camera[:3, 3] = eye
    w, h = 640, 480
    K = np.array([[w, 0, (w - 1) / 2], [0, w, (h - 1) / 2], [0, 0, 1.0]])
    return K, world_from_camera, w, h


def _frame(client: int, camera: tuple, width_px: int, body_ids: dict[int, int]
           ) -> tuple[Frame, np.ndarray]:
    """The picture (with the object id at each pixel) and the scaled ``K`` it was taken with."""
    K, world_from_camera, w, h = camera
    scale = min(1.0, width_px / w)
    K_scaled = scaled_intrinsics(K, scale)
    rgb, bodies = render(client, K_scaled, world_from_camera,
                         max(1, round(w * scale)), max(1, round(h * scale)))
    object_ids = np.full(bodies.shape, -1, dtype=np.int64)
    for obj_id, body in body_ids.items():
        object_ids[bodies == body] = obj_id
    return Frame(rgb, object_ids), K_scaled


def _png_bytes(image: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG")
    return buf.getvalue()


# ---- the stage -------------------------------------------------------------------------


@dataclass
class _Simulated:
    """What the PyBullet part of the judge found."""

    loaded: LoadedScene
    pen: PenetrationMetrics
    traj: Trajectory
    frames: Optional[tuple[Frame, Frame]]
    pybullet_traj: Optional[Trajectory] = None     # the rollout the frames show
    picture_camera: Optional[tuple[np.ndarray, np.ndarray]] = None  # (K, world_from_camera)


def _simulate(paths: ScenePaths, options: Options, progress: ProgressFn, model: dict
              ) -> _Simulated:
    """Load export/ into a fresh DIRECT client: penetration, first frame, rollout, last frame."""
    client = connect_direct()
    try:
        loaded = load_export_scene(client, paths.export)
        pen = penetration_metrics(scene_distances(client, loaded), options.floating_gap_mm)
        first = None
        if options.render:
            camera = _camera(paths, loaded, model)
            colour_bodies(client, loaded.body_ids, loaded.support_body)
            first, K_scaled = _frame(client, camera, options.render_width_px, loaded.body_ids)
        progress("rollout", 0.1)
        traj = rollout(client, loaded, options.duration_s, options.rate_hz, options.record_hz,
                       progress=lambda m, f: progress(m, 0.1 + 0.3 * f))
        frames = None
        if options.render:
            frames = (first, _frame(client, camera, options.render_width_px, loaded.body_ids)[0])
    finally:
        pb.disconnect(physicsClientId=client)
    sim = _Simulated(loaded, pen, traj, frames, pybullet_traj=traj)
    if options.render:
        sim.picture_camera = (K_scaled, camera[1])
    return sim


def _caption(sim: _Simulated, per_stab: list) -> str:
    return (f"{sum(o.stable for o in per_stab)}/{len(per_stab)} objects stable after "
            f"{sim.traj.duration_s:.1f} s  |  max penetration {sim.pen.max_penetration_mm:.1f} mm"
            f"  |  {sim.pen.floating_objects} floating")


def run(ctx: StageContext) -> dict:
    paths, options, progress = ctx.paths, ctx.options, ctx.progress
    if not paths.export_scene.is_file():
        raise StageError(f"{paths.export_scene} is missing; run 'r2s export' first")

    progress("loading export/", 0.0)
    sim = _simulate(paths, options, progress, ctx.manifest.model)
    pen, export_objects = sim.pen, sim.loaded.scene.objects
    if options.engine == "mujoco":
        from r2s.sim.mujoco_rollout import mujoco_rollout

        progress("MuJoCo rollout", 0.35)
        sim.traj = mujoco_rollout(paths.export, options.duration_s, options.record_hz)
    per_stab = object_stability(sim.traj, options.stable_translation_m, options.stable_rotation_deg)
    gt = read_gt_scene(paths.gt_scene)

    if gt is not None:
        progress("geometry against gt/", 0.4)
    geometry = _geometry_per_object(paths, export_objects, gt, options)
    objects: list[dict] = []
    for k, (obj, stab) in enumerate(zip(export_objects, per_stab)):
        entry: dict[str, Any] = {"id": obj.id, "label": obj.label, "source": _source(obj)}
        entry.update(stab.as_dict())
        entry.update(penetration_mm=float(pen.per_object_penetration_mm[k]),
                     gap_mm=float(pen.per_object_gap_mm[k]), floating=bool(pen.floating[k]))
        entry.update(geometry[k])
        objects.append(entry)

    scene: dict[str, Any] = dict(scene_stability(per_stab))
    scene.update(max_penetration_mm=pen.max_penetration_mm,
                 mean_penetration_mm=pen.mean_penetration_mm,
                 floating_objects=pen.floating_objects,
                 fscore_threshold_mm=options.fscore_threshold_mm)
    for key in GEOMETRY_KEYS:
        scene[key] = _mean_or_none([o[key] for o in objects])
    progress("rendering metrics", 0.96)
    rendering, view = _rendering(paths, export_objects, ctx.manifest.model)
    scene.update({k: rendering[k] for k in ("psnr", "ssim", "lpips")})
    progress("observation metrics", 0.98)
    observed, observation_image, observation_reason = _observation(
        paths, export_objects, ctx.manifest.model, sim.loaded.scene.support)
    scene.update(_add_observation(objects, export_objects, observed))
    scene = {key: _finite_or_none(scene[key]) for key in SCENE_KEYS}

    export_ids = {o.id for o in export_objects}
    gt_ids = {o.id for o in gt.objects} if gt is not None else set()
    atomic_write_json(ctx.out_dir / METRICS_FILE, {
        "format": "r2s-metrics", "version": 1,
        **scene,
        "objects": objects,
        "penetration": {
            "object_max_penetration_mm": pen.object_max_penetration_mm,
            "object_mean_penetration_mm": pen.object_mean_penetration_mm,
            "penetrating_pairs": [{"id_a": a, "id_b": b, "depth_mm": d}
                                  for a, b, d in pen.penetrating_pairs],
            "support_id": SUPPORT_ID,
            "pybullet_mesh_margin_m": PYBULLET_MESH_MARGIN_M,
        },
        "rendering": rendering,
        "observation": {"measured": observed is not None, "reason": observation_reason or None,
                        "missing_ids": observed.missing_ids if observed is not None else []},
        "engine": options.engine,
        "rollout": {"duration_s": sim.traj.duration_s, "samples": int(len(sim.traj.times_s))},
        "gt": {"present": gt is not None, "matched_ids": sorted(export_ids & gt_ids),
               "missing_in_export": sorted(gt_ids - export_ids)},
        "options": options.model_dump(mode="json"),
    })
    if sim.frames is not None:
        motions = object_motions(sim.pybullet_traj, {o.id: o.label for o in export_objects})
        picture = rollout_picture(
            sim.frames[0], sim.frames[1], motions, *sim.picture_camera,
            sim.pybullet_traj.duration_s, _caption(sim, per_stab),
            unstable_ids=[s.id for s in per_stab if not s.stable])
        atomic_write_bytes(ctx.out_dir / "rollout.png", _png_bytes(picture))
    if view is not None:
        side_by_side_png(view[0], view[1], ctx.out_dir / "render.png", object_mask=view[2])
    if observation_image is not None and options.render:
        atomic_write_bytes(ctx.out_dir / "observation.png", _png_bytes(observation_image))
    progress("done", 1.0)
    return scene


STAGE = StageSpec("evaluate", Options, inputs, run, uses_model=frozenset({"input"}))
