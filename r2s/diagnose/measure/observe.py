"""Measure every residual group of a scene from loaded data (no scene-folder I/O here).

Inputs are the (model-corrected) :class:`r2s.io.input_scene.InputScene` and the
reconstructed objects as :class:`ObjectModel` (mesh in the object frame, pose, physics);
outputs are the :mod:`r2s.diagnose.data` containers.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Optional

import numpy as np
import trimesh
from scipy import ndimage

from r2s.console import ProgressFn, silent_progress
from r2s.diagnose.data import (DepthMapData, InteractionData, PhysObject, PhysicsData,
                               PhysicsModel, RegistrationData, ScaleObs, SupportData,
                               TableShapeData)
from r2s.diagnose.measure.interaction import Push, simulate_push, simulate_push_motion
from r2s.diagnose.measure.physics import (BodySpec, WorldSpec, rollout_motion, support_contacts,
                                          write_pieces)
from r2s.diagnose.stats.noise import scale_noise_level
from r2s.diagnose.stats.table_height import declares_table
from r2s.diagnose.measure.scale_fit import (INLIER_M, LOG_SCALE_BOUNDS, SurfaceModel,
                                           fit_prior_scale, free_space)
from r2s.geometry.camera import backproject, camera_center, instance_points, pixel_rays
from r2s.geometry.convex_cache import cached_convex_decomposition
from r2s.geometry.convex_params import DEFAULT_CONVEX, ConvexParams
from r2s.geometry.mass_properties import mass_properties
from r2s.geometry.plane import fit_support_plane, signed_distance
from r2s.geometry.raycast import raycast_view
from r2s.geometry.sanity import prior_size_ratio, priors_disagree_with_depth
from r2s.io.input_scene import InputScene
from r2s.physical.density_table import density_for_label


@dataclass(frozen=True)
class ObjectModel:
    """One reconstructed object, loaded.

    mesh : object frame; world_from_object : (4, 4); prior_area_m2 : surface area of its
    metric prior (None when it has none: its size says nothing about the depth);
    mass_kg, com_in_object, friction : None where the state has no value.
    """

    id: int
    label: str
    mesh: trimesh.Trimesh
    world_from_object: np.ndarray
    prior_area_m2: Optional[float] = None
    mass_kg: Optional[float] = None
    com_in_object: Optional[np.ndarray] = None
    friction: Optional[float] = None


@dataclass(frozen=True)
class FitQuality:
    """How well an object's shape fits its observed points (rigid or free-scale fit)."""

    scale_obs: Optional[ScaleObs]
    fitness: float
    rmse_m: float


def object_points_camera(inp: InputScene, obj_id: int, erode_px: int = 1) -> np.ndarray:
    """(N, 3) camera-frame points of one instance (mask eroded against mixed pixels)."""
    mask = inp.masks == obj_id
    if erode_px > 0:
        eroded = ndimage.binary_erosion(mask, iterations=erode_px)
        mask = eroded if eroded.sum() >= 30 else mask
    return backproject(inp.depth_m, inp.camera.K, np.eye(4), mask=mask)


RIGHT_UNIT_SIZE_RATIO = 1.29
"""Median over a scene's priors of prior size / observed size
(:func:`r2s.geometry.sanity.prior_size_ratio`) with a right depth unit: the geometric
middle of the 1.08-1.53 measured on 41 such scenes (docs/diagnose.md, section 2)."""


def start_scale(inp: InputScene, objects: list[ObjectModel],
                points: Optional[dict[int, np.ndarray]] = None) -> float:
    """Where the free-scale fits start: 1, or, when the priors taken together are another
    size than the depth shows (init's warning,
    :func:`r2s.geometry.sanity.priors_disagree_with_depth`; a depth unit off by 2, say),
    the depth scale their sizes suggest, ``RIGHT_UNIT_SIZE_RATIO / median ratio``.
    ``points``: id -> :func:`object_points_camera` where already computed."""
    ratios = []
    for o in objects:
        if o.prior_area_m2 is None or o.prior_area_m2 <= 0:
            continue
        pts = points[o.id] if points is not None else object_points_camera(inp, o.id)
        if len(pts) >= 30:
            ratios.append(prior_size_ratio(o.mesh, pts))
    if priors_disagree_with_depth(ratios) is None:
        return 1.0
    return RIGHT_UNIT_SIZE_RATIO / float(np.median(ratios))


def start_from_view(mesh: trimesh.Trimesh, object_from_camera: np.ndarray,
                    points_camera: np.ndarray, scale: float) -> np.ndarray:
    """(4, 4) start of a free-scale fit at ``scale`` when init's registration cannot be
    one (it fitted the prior at scale 1 into an observation ``scale`` times its size):
    init's rotation, the observation shrunk by ``scale``, and its centroid on the centroid
    of the mesh's vertices that face the camera (the side the camera sees)."""
    rot = np.asarray(object_from_camera, dtype=np.float64)[:3, :3]
    centre = points_camera.mean(axis=0)
    view_dir = rot @ (centre / max(float(np.linalg.norm(centre)), 1e-9))  # object frame
    facing = np.asarray(mesh.vertex_normals) @ view_dir < -0.2
    verts = np.asarray(mesh.vertices)
    seen = verts[facing].mean(axis=0) if facing.any() else verts.mean(axis=0)
    out = np.eye(4)
    out[:3, :3] = rot / scale
    out[:3, 3] = seen - out[:3, :3] @ centre
    return out


def fit_quality(inp: InputScene, obj: ObjectModel, seed: int = 0,
                scale_start: float = 1.0, pts: Optional[np.ndarray] = None) -> FitQuality:
    """Free-scale fit for an object with a metric prior, rigid fit otherwise. With a
    ``scale_start`` other than 1 (:func:`start_scale`) a prior is fitted a second time,
    from there (:func:`start_from_view`) within 0.7-1.4 times it, its points counted as
    fitting within ``INLIER_M`` times that start (the prior's units: a depth read s times
    long has its noise s times larger too), and the fit that explains more of the observed
    points is kept: a scene warned about wrongly still has its fit from init's pose at
    scale 1. ``pts``: its :func:`object_points_camera` where already computed."""
    if pts is None:
        pts = object_points_camera(inp, obj.id)
    if len(pts) < 30:
        return FitQuality(None, 0.0, float("nan"))
    view = free_space(inp.camera.K, inp.depth_m, inp.masks == obj.id)
    object_from_camera = np.linalg.inv(obj.world_from_object) @ inp.camera.world_from_camera
    has_prior = obj.prior_area_m2 is not None and obj.prior_area_m2 > 0
    model = SurfaceModel(obj.mesh)
    fit = fit_prior_scale(model, pts, object_from_camera, fit_scale=has_prior, seed=seed,
                          view=view, free_space_weight=0.5)
    if has_prior and scale_start != 1.0:
        shift = float(np.log(scale_start))
        other = fit_prior_scale(model, pts,
                                start_from_view(obj.mesh, object_from_camera, pts, scale_start),
                                seed=seed, view=view, free_space_weight=0.5,
                                inlier_m=INLIER_M * scale_start,
                                log_scale_bounds=(LOG_SCALE_BOUNDS[0] + shift,
                                                  LOG_SCALE_BOUNDS[1] + shift))
        if (other.fitness, -other.rmse_m) > (fit.fitness, -fit.rmse_m):
            fit = other
    obs = None
    if has_prior:
        state_vs_prior = float(np.sqrt(obj.mesh.area / obj.prior_area_m2))
        obs = ScaleObs(id=obj.id, scale=fit.scale * state_vs_prior,
                       depth_m=float(np.median(pts[:, 2])), fitness=fit.fitness,
                       rmse_m=fit.rmse_m, n_points=fit.n_points)
    return FitQuality(obs, fit.fitness, fit.rmse_m)


def registration_residual(qualities: dict[int, FitQuality], scale_sigma: float,
                          min_fitness: float, prior_scale_sigma: float = 0.02,
                          prior_scale_dof: float = 4.0, min_points: int = 0) -> RegistrationData:
    """Per-object prior scales. The noise level is measured on them, pooled with a prior
    spread (:func:`r2s.diagnose.stats.noise.scale_noise_level`, ``scale_sigma`` its floor):
    priors err in size independently, a depth bias moves them all together, so their
    spread measures the priors' error."""
    objs = tuple(q.scale_obs for _, q in sorted(qualities.items()) if q.scale_obs is not None)
    data = RegistrationData(objects=objs, scale_sigma=scale_sigma, min_fitness=min_fitness,
                            min_points=min_points)
    logs = np.log([o.scale for o in data.used()])
    prior = (prior_scale_sigma, prior_scale_dof)
    sigma, dof = scale_noise_level(logs, scale_sigma, *prior)
    return RegistrationData(objects=objs, scale_sigma=sigma, min_fitness=min_fitness,
                            min_points=min_points,
                            scale_floor=scale_sigma, noise_dof=dof, noise_prior=prior)


def support_residual(inp: InputScene, gravity: np.ndarray, sigma_rad: float,
                     max_points: int = 60000, seed: int = 0, height_sigma_m: float = 0.002,
                     table_height: str = "auto") -> Optional[SupportData]:
    """RANSAC plane of the table pixels (mask 0) against the model's gravity.

    ``table_height``: whether the table's height at the declared world's origin is evidence
    ("auto": when the declared world evidently puts the table there,
    :func:`r2s.diagnose.stats.table_height.declares_table`; "on"; "off")."""
    pts = backproject(inp.depth_m, inp.camera.K, inp.camera.world_from_camera,
                      mask=inp.masks == 0)
    if len(pts) < 100:
        return None
    if len(pts) > max_points:
        pts = pts[np.random.default_rng(seed).choice(len(pts), max_points, replace=False)]
    up = -np.asarray(gravity, dtype=np.float64)
    up /= np.linalg.norm(up)
    centre = camera_center(inp.camera.world_from_camera)
    try:
        objects = instance_points(inp.depth_m, inp.camera.K, inp.camera.world_from_camera,
                                  inp.masks, inp.ids, np.random.default_rng(seed), 4000)
        plane = fit_support_plane(pts, objects, threshold_m=0.004,
                                  iterations=400, seed=seed, up_hint=up, viewpoint=centre,
                                  max_tilt_deg=30.0)
    except ValueError:
        return None
    inl = pts[plane.inliers]
    if len(inl) > 5000:
        inl = inl[np.random.default_rng(seed).choice(len(inl), 5000, replace=False)]
    camera_from_world = np.linalg.inv(inp.camera.world_from_camera)
    data = SupportData(normal=plane.normal, point=plane.point, up=up, sigma_rad=sigma_rad,
                       camera_center=centre, n_points=int(plane.inliers.sum()),
                       points_camera=inl @ camera_from_world[:3, :3].T + camera_from_world[:3, 3],
                       world_from_camera=np.asarray(inp.camera.world_from_camera),
                       height_sigma_m=float(height_sigma_m))
    used = table_height == "on" or (table_height == "auto" and declares_table(data))
    return replace(data, height_used=bool(used))


TABLE_BAND_M = 0.05
"""Background pixels farther than this from the support plane are not the table (the
floor or a wall seen past its edge); they are left out of the table's residuals."""


def table_pixels(inp: InputScene, support: Optional[SupportData]) -> np.ndarray:
    """(H, W) bool: background pixels (mask 0) with a reading, within
    :data:`TABLE_BAND_M` of the support plane when one is given."""
    mask = (inp.masks == 0) & np.isfinite(inp.depth_m) & (inp.depth_m > 0)
    if support is None:
        return mask
    rows, cols = np.nonzero(mask)
    pts = backproject(inp.depth_m, inp.camera.K, inp.camera.world_from_camera, mask=mask)
    far = np.abs(signed_distance(pts, support.point, support.normal)) > TABLE_BAND_M
    mask[rows[far], cols[far]] = False
    return mask


def table_shape_residual(inp: InputScene, sigma_m: float, max_points: int = 20000,
                         seed: int = 0, support: Optional[SupportData] = None
                         ) -> Optional[TableShapeData]:
    """Every table pixel with a reading (:func:`table_pixels`), back-projected into the
    camera frame (a seeded subsample), with its grey level."""
    mask = table_pixels(inp, support)
    rows, cols = np.nonzero(mask)
    if len(rows) < 100:
        return None
    if len(rows) > max_points:
        pick = np.sort(np.random.default_rng(seed).choice(len(rows), max_points, replace=False))
        rows, cols = rows[pick], cols[pick]
    K = np.asarray(inp.camera.K, dtype=np.float64)
    z = inp.depth_m[rows, cols].astype(np.float64)
    x = (cols - K[0, 2] - K[0, 1] * (rows - K[1, 2]) / K[1, 1]) / K[0, 0]
    y = (rows - K[1, 2]) / K[1, 1]
    pts = np.stack([x * z, y * z, z], axis=1)
    grey = grey_image(inp)
    if grey is not None:
        grey = grey[rows, cols]
    return TableShapeData(points_camera=pts, K=K, width=int(inp.camera.width),
                          height=int(inp.camera.height), grey=grey, sigma_m=sigma_m)


def grey_image(inp: InputScene) -> Optional[np.ndarray]:
    """(H, W) grey level 0..1 of the input image (the mean of its channels), or None
    without a colour image."""
    if inp.rgb is None or np.asarray(inp.rgb).ndim != 3:
        return None
    return np.asarray(inp.rgb, dtype=np.float64).mean(axis=2) / 255.0


def depth_residual_map(inp: InputScene, objects: list[ObjectModel],
                       support: Optional[SupportData]) -> DepthMapData:
    """Observed minus rendered depth: objects where the rendered id matches, table pixels
    against the fitted plane."""
    cam = inp.camera
    meshes = [o.mesh.copy().apply_transform(o.world_from_object) for o in objects]
    rendered, index, triangle = raycast_view(meshes, cam.K, cam.world_from_camera, cam.width,
                                             cam.height)
    ids = np.array([o.id for o in objects] + [-1])
    rendered_id = np.where(index >= 0, ids[np.clip(index, 0, len(objects))], 0)
    obs = inp.depth_m.astype(np.float64)
    residual = np.full(obs.shape, np.nan)
    on_obj = (inp.masks > 0) & (rendered_id == inp.masks)
    residual[on_obj] = obs[on_obj] - rendered[on_obj]
    if support is not None:
        plane_depth = _plane_depth(cam.K, cam.world_from_camera, support.point, support.normal,
                                   cam.width, cam.height)
        table = table_pixels(inp, support) & np.isfinite(plane_depth)
        residual[table] = obs[table] - plane_depth[table]
    return DepthMapData(residual_m=residual, depth_m=obs, on_object=inp.masks > 0,
                        object_id=np.where(on_obj, inp.masks, 0).astype(np.int64),
                        grey=grey_image(inp),
                        prior_ids=tuple(o.id for o in objects if o.prior_area_m2 is not None),
                        view_cosine=_view_cosine(meshes, index, triangle, cam.K,
                                                 cam.world_from_camera),
                        masks=np.asarray(inp.masks))


def _view_cosine(meshes_world: list, index: np.ndarray, triangle: np.ndarray, K: np.ndarray,
                 world_from_camera: np.ndarray) -> np.ndarray:
    """(H, W) |cosine| between each pixel's ray and the normal of the rendered triangle it
    hits (NaN where none): 1 facing the camera, 0 grazing."""
    height, width = index.shape
    _, dirs = pixel_rays(K, world_from_camera, width, height)
    out = np.full(index.shape, np.nan)
    for k, mesh in enumerate(meshes_world):
        hit = (index == k) & (triangle >= 0)
        if hit.any():
            normals = np.asarray(mesh.face_normals)[triangle[hit]]
            ray = dirs[hit] / np.linalg.norm(dirs[hit], axis=1, keepdims=True)
            out[hit] = np.abs(np.sum(normals * ray, axis=1))
    return out


def _plane_depth(K: np.ndarray, world_from_camera: np.ndarray, point: np.ndarray,
                 normal: np.ndarray, width: int, height: int) -> np.ndarray:
    """(H, W) camera depth of the plane along every pixel ray (NaN when behind)."""
    camera_from_world = np.linalg.inv(world_from_camera)
    n_c = camera_from_world[:3, :3] @ np.asarray(normal, dtype=np.float64)
    p_c = camera_from_world[:3, :3] @ np.asarray(point, dtype=np.float64) + camera_from_world[:3, 3]
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    rays = np.stack([u, v, np.ones_like(u)], axis=-1) @ np.linalg.inv(K).T  # z = 1
    denom = rays @ n_c
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (n_c @ p_c) / denom
    return np.where(z > 0, z, np.nan)


def world_spec(objects: list[ObjectModel], support_point: np.ndarray,
               support_normal: np.ndarray, support_friction: float, cache_dir: Optional[Path],
               density_kg_m3: Optional[float] = None, default_friction: float = 0.8,
               convex: ConvexParams = DEFAULT_CONVEX) -> WorldSpec:
    """Rigid bodies for PyBullet (convex pieces written to a temporary folder).

    Mass, COM, friction and collision pieces as the export stage makes them (pass its
    options): volume x density (None: the label's density, r2s.physical.density_table),
    the shape's centroid, ``default_friction``, CoACD pieces.
    """
    tmp = tempfile.TemporaryDirectory(prefix="r2s-diagnose-")
    bodies = []
    for o in objects:
        pieces = cached_convex_decomposition(o.mesh, cache_dir, **convex.as_kwargs())
        rho = (density_kg_m3 if density_kg_m3 is not None
               else density_for_label(o.label).density_kg_m3)
        props = mass_properties(o.mesh, pieces, mass_kg=o.mass_kg, density_kg_m3=rho)
        com = props.com_in_object if o.com_in_object is None else np.asarray(o.com_in_object)
        files = write_pieces(pieces, Path(tmp.name), str(o.id))
        ext = o.mesh.bounds[1] - o.mesh.bounds[0]
        bodies.append(BodySpec(id=o.id, files=files, world_from_object=o.world_from_object,
                               mass_kg=props.mass_kg, com_in_object=np.asarray(com, dtype=float),
                               friction=default_friction if o.friction is None else o.friction,
                               radius_m=float(0.5 * np.linalg.norm(ext)), mesh=o.mesh))
    return WorldSpec(bodies, np.asarray(support_point, dtype=float),
                     np.asarray(support_normal, dtype=float), float(support_friction), keep=tmp)


def physics_residual(spec: WorldSpec, gravity: np.ndarray, geometry_ok: dict[int, bool],
                     horizon_s: float, sigma_translation_m: float, sigma_rotation_rad: float,
                     cap: float) -> PhysicsData:
    """Rollout under the model's gravity, with the contacts each object rests on."""
    base = PhysicsModel(gravity=np.asarray(gravity, dtype=np.float64))
    motion = rollout_motion(spec, base, horizon_s)
    contacts, neighbours = support_contacts(spec, -base.gravity)
    objects = {}
    for b in spec.bodies:
        pose = np.asarray(b.world_from_object)
        objects[b.id] = PhysObject(
            id=b.id, com_world=pose[:3, :3] @ b.com_in_object + pose[:3, 3],
            support_contacts_world=contacts.get(b.id, np.zeros((0, 3))), radius_m=b.radius_m,
            geometry_ok=bool(geometry_ok.get(b.id, False)), friction=b.friction,
            world_from_object=pose, com_in_object=np.asarray(b.com_in_object),
            neighbours=frozenset(neighbours.get(b.id, set())))

    def simulate(model: PhysicsModel) -> dict:
        return rollout_motion(spec, model, horizon_s)

    return PhysicsData(base=base, objects=objects, motion=motion, simulate=simulate,
                       horizon_s=horizon_s, sigma_translation_m=sigma_translation_m,
                       sigma_rotation_rad=sigma_rotation_rad, cap=cap)


def interaction_residual(spec: WorldSpec, base: PhysicsModel, push: Push, observed: dict,
                         sigma_m: float, rest: Optional[PhysicsData] = None,
                         stage: Optional[str] = None,
                         observed_tilt_rad: Optional[dict] = None) -> InteractionData:
    """The push simulated on ``spec`` under ``base``, against ``observed`` displacements.

    With ``rest`` (its noise levels and horizon), ``spec`` is also rolled out without the
    push, and the objects that stay within ``rest``'s noise are ``resting_ids``: only
    their simulated push measures friction rather than the reconstruction's own motion.
    """
    def simulate(model: PhysicsModel) -> dict:
        return simulate_push(spec, model, push)

    motion = simulate_push_motion(spec, base, push)
    predicted = {i: m.translation_m for i, m in motion.items()}
    known = {i: d for i, d in observed.items() if i in predicted}
    resting = None
    if rest is not None:
        still = rollout_motion(spec, base, rest.horizon_s)
        resting = frozenset(i for i in still if i not in rest.moving(still))
    return InteractionData(observed_m=known, predicted_m=predicted, simulate=simulate,
                           sigma_m=sigma_m, pushed_ids=tuple(sorted(known)),
                           resting_ids=resting, stage=stage,
                           observed_tilt_rad=dict(observed_tilt_rad or {}),
                           predicted_tilt_rad={i: m.tilt_rad(-base.gravity)
                                               for i, m in motion.items()},
                           simulate_motion=lambda model: simulate_push_motion(spec, model, push))


def measure_fit_qualities(inp: InputScene, objects: list[ObjectModel],
                          progress: ProgressFn = silent_progress) -> dict[int, FitQuality]:
    out = {}
    points = {o.id: object_points_camera(inp, o.id) for o in objects}
    scale = start_scale(inp, objects, points)
    for k, o in enumerate(objects):
        progress(f"registration of object {o.id}", k / max(len(objects), 1))
        out[o.id] = fit_quality(inp, o, scale_start=scale, pts=points[o.id])
    return out
