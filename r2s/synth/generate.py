"""``r2s synth``: make one benchmark scene (input/ + gt/) from a seed.

Steps: pick objects from the catalogue, drop them into a clutter and verify it is at rest
(:mod:`~r2s.synth.physics`), place a camera looking down at 40-70 degrees, render RGB,
depth and instance masks (:mod:`~r2s.synth.render`), degrade the depth
(:mod:`~r2s.synth.depth_noise`), make shape priors (:mod:`~r2s.synth.priors`), apply the
injected effects (:mod:`~r2s.synth.effects`) and write everything into a scratch folder
that replaces ``out_dir`` at the end. The same options give byte-identical files.

Layout written (SCENE_FORMAT.md)::

    OUT/input/{rgb.png, depth.png, masks.png, camera.json, objects.json, priors/<id>.glb}
    OUT/gt/{scene.json, meshes/<id>.glb}
    OUT/input/interaction/, OUT/gt/push.json   with ``push`` (:mod:`~r2s.synth.push`)
    OUT/.cache/convex/<key>.npz    the export stage's memo of the gt collision pieces
"""

from __future__ import annotations

import json
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import trimesh

from r2s.console import ProgressFn, silent_progress
from r2s.errors import R2SError
from r2s.io.atomic import atomic_write_json, commit_dir, recover_dir, scratch_dir
from r2s.io.input_scene import MIN_MASK_PIXELS
from r2s.io.mesh_io import save_mesh
from r2s.io.paths import ScenePaths
from r2s.synth import appearance, camera, catalog, depth_noise, physics, placement, priors, \
    realistic
from r2s.synth.collision import default_cache_dir, prime_scene_cache
from r2s.synth.effects import Effects, distorted_frame, lens_coefficients, parse_effects
from r2s.synth.files import depth_png, write_png, write_textured_obj
from r2s.synth.options import SynthOptions
from r2s.synth.placement import Placed
from r2s.synth.push import add_observed_push
from r2s.synth.render import Frame, Lighting, Visual, render

__all__ = ["SynthOptions", "synthesize"]

DEPTH_UNIT_M = 0.001
GENERATOR = "r2s synth v1"
TABLE_SIZE_M = 3.0

# Independent random streams, so that e.g. the noise level does not change the objects.
_STREAMS = ("select", "body", "place", "effect", "camera", "noise", "prior", "texture", "order",
            "masks", "depthless")  # new streams go at the end: the earlier ones keep their numbers


def _streams(seed: int) -> dict[str, np.random.Generator]:
    return {name: np.random.default_rng([seed, k]) for k, name in enumerate(_STREAMS)}


def _check_out_dir(out_dir: Path) -> None:
    if not out_dir.exists():
        return
    if not out_dir.is_dir():
        raise R2SError(f"{out_dir}: exists and is not a folder")
    if not any(out_dir.iterdir()):
        return
    gt = out_dir / "gt" / "scene.json"
    try:
        previous = json.loads(gt.read_text()) if gt.is_file() else {}
    except (json.JSONDecodeError, UnicodeDecodeError):
        previous = {}
    if "synth" not in previous:
        raise R2SError(f"{out_dir}: not empty and not a scene made by r2s synth; "
                       "choose another folder or remove it")


# ---- camera, rendering, observation --------------------------------------------------------
def _world_points(placed: Placed, per_body: int = 400) -> np.ndarray:
    pts = []
    for body, pose in zip(placed.bodies, placed.poses):
        v = np.asarray(body.mesh.vertices)
        v = v[:: max(1, len(v) // per_body)]
        pts.append(v @ pose[:3, :3].T + pose[:3, 3])
    return np.vstack(pts)


def _camera(placed: Placed, options: SynthOptions, rng: np.random.Generator
            ) -> tuple[np.ndarray, np.ndarray, dict]:
    vfov_deg, record = options.vfov_deg, {}
    if options.camera_model == "realsense":
        hfov_deg = float(rng.uniform(*options.hfov_deg))
        vfov_deg = realistic.vertical_fov_deg(hfov_deg, options.width, options.height)
        record = {"hfov_deg": hfov_deg, "vfov_deg": vfov_deg}
    K = camera.intrinsics(options.width, options.height, vfov_deg)
    points = _world_points(placed)
    target = 0.5 * (points.min(axis=0) + points.max(axis=0))
    target[:2] += rng.normal(0.0, 0.015, size=2)
    elevation = float(rng.uniform(*options.elevation_deg))
    azimuth = float(rng.uniform(0.0, 360.0))
    roll = 0.0
    if tuple(options.camera_roll_deg) != (0.0, 0.0):  # drawn only when asked for: the
        roll = float(rng.uniform(*options.camera_roll_deg))  # level scenes keep their bytes
        record["roll_deg"] = roll
    needed = camera.fit_distance(points, target, elevation, azimuth, K, options.width,
                                 options.height, margin_px=0.08 * options.width, roll_deg=roll)
    distance = float(np.clip(needed * rng.uniform(1.0, 1.3), *options.distance_m))
    pose = camera.orbit_pose(target, elevation, azimuth, distance, roll)
    return K, pose, {"elevation_deg": elevation, "azimuth_deg": azimuth,
                     "distance_m": distance, "target": target, **record}


def _lighting(rng: np.random.Generator) -> Lighting:
    a = rng.uniform(0, 2 * np.pi)
    direction = np.array([np.cos(a), np.sin(a), rng.uniform(1.2, 2.5)])
    return Lighting(direction=direction / np.linalg.norm(direction),
                    ambient=float(rng.uniform(0.55, 0.7)), diffuse=float(rng.uniform(0.3, 0.45)),
                    specular=float(rng.uniform(0.02, 0.08)))


def _table_visual(support: physics.Support, rng: np.random.Generator, work: Path) -> Visual:
    box = trimesh.creation.box([TABLE_SIZE_M, TABLE_SIZE_M, 0.02])
    box.apply_translation([0, 0, -0.01])
    uv = (np.asarray(box.vertices)[:, :2] + TABLE_SIZE_M / 2) / TABLE_SIZE_M
    box.visual = trimesh.visual.TextureVisuals(uv=np.clip(uv, 0, 1))
    write_textured_obj(work / "table.obj", box)
    image, _kind = appearance.table_texture(rng, 1024)
    write_png(work / "table.png", image)
    pose = np.eye(4)
    pose[:3, :3] = physics.plane_rotation(support.normal)
    pose[:3, 3] = support.point
    return Visual(work / "table.obj", work / "table.png", pose)


def _object_visuals(placed: Placed, rng: np.random.Generator, work: Path) -> list[Visual]:
    visuals = []
    for k, (body, pose) in enumerate(zip(placed.bodies, placed.poses)):
        entry = catalog.CATALOG[body.name]
        folder = work / f"visual_{k + 1}"
        folder.mkdir()
        write_textured_obj(folder / "mesh.obj", appearance.cylindrical_uv(body.mesh))
        write_png(folder / "albedo.png", appearance.texture_image(
            entry.pattern, entry.colour, entry.accent, rng))
        visuals.append(Visual(folder / "mesh.obj", folder / "albedo.png", pose))
    return visuals


@dataclass(frozen=True)
class _Observation:
    rgb: np.ndarray
    depth_m: np.ndarray
    masks: np.ndarray
    visible_px: np.ndarray
    in_input: np.ndarray


def _observe(frame: Frame, K: np.ndarray, options: SynthOptions, effects: Effects,
             rng: np.random.Generator, n: int) -> _Observation:
    depth = depth_noise.observe_depth(
        frame.depth_m, K, rng, options.noise,
        scale=effects.depth_scale if effects.depth_scale is not None else 1.0,
        offset_m=effects.depth_offset_m or 0.0)
    masks = np.zeros(frame.segment.shape, dtype=np.uint8)
    visible_px = np.zeros(n, dtype=np.int64)
    in_input = np.zeros(n, dtype=bool)
    for k in range(n):
        seen = frame.segment == k
        visible_px[k] = int(seen.sum())
        valid = int((seen & np.isfinite(depth)).sum())
        if visible_px[k] >= options.min_visible_px and valid >= MIN_MASK_PIXELS:
            in_input[k] = True
            masks[seen] = k + 1
    rgb = frame.rgb.astype(np.float64)
    rgb += rng.normal(0.0, 2.0 * min(options.noise, 1.0), size=rgb.shape)
    return _Observation(rgb=np.clip(np.round(rgb), 0, 255).astype(np.uint8), depth_m=depth,
                        masks=masks, visible_px=visible_px, in_input=in_input)


# ---- writing ------------------------------------------------------------------------------
def _as_list(pose: np.ndarray) -> list[list[float]]:
    return [[float(x) for x in row] for row in np.asarray(pose)]


def _jsonable(value: object) -> object:
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items() if not str(k).startswith("_")}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def synthesize(out_dir: Path, options: SynthOptions,
               progress: ProgressFn = silent_progress) -> dict:
    """Make one benchmark scene in ``out_dir`` (replaced atomically).

    Raises :class:`R2SError` for bad options, for an ``out_dir`` that holds something
    other than a previous synth scene, and when no scene at rest could be made.

    Returns
    -------
    summary dict: ``objects`` (in gt/), ``visible`` (in input/), ``priors``, ``stacked``
    (objects resting only on other objects), ``contacts`` (touching object pairs),
    ``pushed_id`` (with ``push``), ``seconds``.
    """
    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    effects = parse_effects(options.effects)
    entries = catalog.entries_for(options.objects)
    recover_dir(out_dir)
    _check_out_dir(out_dir)
    rngs = _streams(options.seed)
    cache_dir = Path(options.cache_dir) if options.cache_dir else default_cache_dir()
    work = Path(tempfile.mkdtemp(prefix="r2s-synth-"))
    scratch: Optional[Path] = None
    try:
        support, tilt_record = placement.make_support(options, effects, rngs["effect"])
        stream = placement.body_stream(entries, options, effects, rngs, work, cache_dir)
        placed, com_record = placement.place(stream, options, effects, support, rngs, progress)
        contacts = physics.contact_summary(placed.bodies, placed.poses, support)

        progress("rendering", 0.6)
        K, true_pose, camera_record = _camera(placed, options, rngs["camera"])
        frame = render(_object_visuals(placed, rngs["texture"], work),
                       _table_visual(support, rngs["texture"], work), K, true_pose,
                       options.width, options.height, _lighting(rngs["camera"]))
        n = len(placed.bodies)
        frame = distorted_frame(frame, K, effects)
        realism_record: dict = {}
        if (options.depth_model == "default" and options.mask_model == "exact"
                and options.depthless == 0):
            obs = _observe(frame, K, options, effects, rngs["noise"], n)
        else:
            real = realistic.observe(frame, K, options, effects, rngs["noise"], rngs["masks"], n,
                                     depthless_rng=rngs["depthless"])
            obs = _Observation(rgb=real.rgb, depth_m=real.depth_m, masks=real.masks,
                               visible_px=real.visible_px, in_input=real.in_input)
            realism_record = real.record
        if not obs.in_input.any():
            raise R2SError("no object is visible from the sampled camera (try another seed)")

        written_pose = true_pose
        injected: dict = {}
        if effects.camera_rotation_deg:
            axis = camera.random_unit_vector(rngs["effect"])
            written_pose = camera.rotated_about_centre(true_pose, axis,
                                                       effects.camera_rotation_deg)
            injected["camera_rotation_deg"] = {
                "value": effects.camera_rotation_deg, "axis_world": axis,
                "true_world_from_camera": _as_list(true_pose),
                "written_world_from_camera": _as_list(written_pose)}
        if effects.depth_scale is not None:
            injected["depth_scale"] = {"value": effects.depth_scale}
        if effects.depth_offset_m is not None:
            injected["depth_offset_m"] = {"value": effects.depth_offset_m}
        if lens_coefficients(effects) is not None:
            injected["lens_distortion"] = dict(zip(("k1", "k2"), lens_coefficients(effects)))
        if effects.friction is not None:
            injected["friction"] = {"value": effects.friction, "objects": "all"}
        if tilt_record:
            injected["table_tilt_deg"] = tilt_record
        shifted_ids: dict[int, dict] = {}
        if com_record:
            by_body = com_record["_shifted"]
            for k, body in enumerate(placed.bodies):
                if id(body) in by_body:
                    shifted_ids[k + 1] = by_body[id(body)]
            injected["com_offset_m"] = {
                "value": com_record["value"], "scope": com_record["scope"],
                "objects": [{"id": i, **rec} for i, rec in sorted(shifted_ids.items())]}

        progress("writing", 0.8)
        scratch = scratch_dir(out_dir)
        paths = ScenePaths(scratch)
        (paths.input / "priors").mkdir(parents=True)
        (paths.gt / "meshes").mkdir(parents=True)
        write_png(paths.rgb, obs.rgb)
        write_png(paths.depth_png, depth_png(obs.depth_m, DEPTH_UNIT_M))
        write_png(paths.masks, obs.masks)
        if realism_record:
            realistic.write_gt_images(paths.gt, real)
        atomic_write_json(paths.camera, {
            "width": options.width, "height": options.height, "K": _as_list(K),
            "world_from_camera": _as_list(written_pose), "depth_unit_m": DEPTH_UNIT_M})

        visible = [k for k in range(n) if obs.in_input[k]]
        n_priors = int(round(options.prior_fraction * len(visible))) \
            if options.prior_model != "none" else 0
        with_prior = set(int(k) for k in rngs["prior"].permutation(visible)[:n_priors]) \
            if visible else set()
        input_objects, gt_objects = [], []
        for k, (body, pose) in enumerate(zip(placed.bodies, placed.poses)):
            obj_id = k + 1
            save_mesh(body.mesh, paths.gt / "meshes" / f"{obj_id}.glb")
            prime_scene_cache(body.mesh, cache_dir, ScenePaths(scratch).convex_cache)
            gt_entry = {
                "id": obj_id, "label": body.name, "mesh": f"meshes/{obj_id}.glb",
                "world_from_object": _as_list(pose), "mass_kg": body.mass_kg,
                "friction": body.friction, "com_in_object": body.com_in_object.tolist(),
                "source": body.extra["source"], "density_kg_m3": body.extra["density_kg_m3"],
                "visible_px": int(obs.visible_px[k]), "in_input": bool(obs.in_input[k]),
                "collision_pieces": len(body.pieces),
            }
            if obs.in_input[k]:
                entry = {"id": obj_id, "label": body.name}
                if k in with_prior and options.prior_model == "single_image":
                    prior_mesh, si_error = priors.make_single_image_prior(body.mesh,
                                                                          rngs["prior"])
                    world_from_prior, angle, shift = pose, 0.0, 0.0
                    if options.prior_pose == "perturbed":
                        world_from_prior, angle, shift = priors.perturb_pose(
                            pose, prior_mesh.centroid, rngs["prior"])
                    save_mesh(prior_mesh, paths.input / "priors" / f"{obj_id}.glb")
                    entry["prior_mesh"] = f"priors/{obj_id}.glb"
                    entry["world_from_prior"] = _as_list(world_from_prior)
                    gt_entry["prior_error"] = {
                        "model": "single_image", "scale": list(si_error.scale),
                        "rotation_deg": angle, "translation_m": shift,
                        "deformation": si_error.deformation, "chamfer_mm": si_error.chamfer_mm,
                        "target_chamfer_mm": si_error.target_chamfer_mm,
                        "smoothing_iterations": si_error.smoothing_iterations,
                        "faces": si_error.faces}
                elif k in with_prior:
                    prior_mesh, error = priors.make_prior_mesh(body.mesh, rngs["prior"])
                    world_from_prior, angle, shift = priors.perturb_pose(
                        pose, prior_mesh.centroid, rngs["prior"])
                    if options.prior_pose == "exact":
                        world_from_prior, angle, shift = pose, 0.0, 0.0
                    save_mesh(prior_mesh, paths.input / "priors" / f"{obj_id}.glb")
                    entry["prior_mesh"] = f"priors/{obj_id}.glb"
                    entry["world_from_prior"] = _as_list(world_from_prior)
                    gt_entry["prior_error"] = {
                        "scale": list(error.scale), "rotation_deg": angle,
                        "translation_m": shift, "surface_noise_m": error.surface_noise_m,
                        "faces": error.faces}
                input_objects.append(entry)
            gt_objects.append(gt_entry)
        atomic_write_json(paths.objects, {"objects": input_objects})
        atomic_write_json(paths.gt_scene, _jsonable({
            "gravity": list(physics.GRAVITY),
            "objects": gt_objects,
            "support": {"type": "plane", "point": support.point.tolist(),
                        "normal": support.normal.tolist(), "friction": support.friction},
            "injected_effects": injected,
            "camera": {"K": _as_list(K), "world_from_camera": _as_list(true_pose),
                       **camera_record},
            "contacts": {"pairs": [[a + 1, b + 1] for a, b in contacts["pairs"]],
                         "stacked_ids": [k + 1 for k in contacts["stacked"]]},
            **({"realism": realism_record} if realism_record else {}),
            "synth": {"generator": GENERATOR, "options": options.record(),
                      "verify": {"duration_s": options.verify_duration_s,
                                 "translation_m": options.verify_translation_m,
                                 "rotation_deg": options.verify_rotation_deg}},
        }))
        pushed: dict = {}
        if options.push:
            progress("pushing", 0.9)
            pushed = add_observed_push(scratch)
        commit_dir(scratch, out_dir)
        scratch = None
    finally:
        shutil.rmtree(work, ignore_errors=True)
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)
    progress("done", 1.0)
    return {"objects": n, "visible": int(obs.in_input.sum()), "priors": len(with_prior),
            "stacked": len(contacts["stacked"]), "contacts": len(contacts["pairs"]),
            **({"pushed_id": pushed["pushed_id"]} if pushed else {}),
            "seconds": round(time.perf_counter() - t0, 2)}
