"""Fit a registered prior to what the camera saw: silhouette, depth, free space, table.

A single-image prior is off by up to ~15 % per axis and carries a smooth deformation;
ICP on the observed points (:mod:`r2s.geometry.registration`) places it well (a few mm of
unilateral Chamfer) but leaves it smaller or larger than the object's mask, floating
above the table or sunk into it. Later stages then move it away from the observation.
This fits pose and a bounded scale per prior axis to the view itself, by ray casting the
scaled prior through the pixels around the instance and scoring (all in pixels squared):

- **silhouette**: a pixel of the instance's mask that the prior does not cover, or a pixel
  the prior covers where the camera saw past it (outside the mask, observed depth behind
  the prior), costs its distance (px, capped) to the other silhouette, summed and divided
  by the mask's outline length, so that an outline shifted by ``d`` px costs about
  ``d^2 / 2 + d``. Pixels where something nearer hides the prior cost nothing; mask rim
  pixels on the far side of a depth jump or on the table (bleed) are not required;
- **depth**: where the prior covers a mask pixel with a reading, the difference between
  the prior's front surface and the observed depth, in pixels at that depth, squared and
  truncated at ``depth_tolerance_m``, averaged;
- **support**: no point below the support plane; a prior registered with its bottom
  within ``rest_contact_m`` of the plane is seen resting there and its bottom is pulled
  onto it;
- **others**: penetration (m, as pixels) of the prior's hull vertices and surface samples
  into the meshes of the other objects, squared, summed and divided by
  ``contact_normaliser`` (a few millimetres over a few dozen samples cost like a pixel of
  outline): the prior shrinks within its scale bounds or moves, whichever the view allows;
- **scale**: ``(log(s_i / s0) / scale_sigma)^2`` per axis: an axis the view does not
  constrain keeps the registration's scale; likewise the turn from the registered
  rotation, ``(angle / rotation_sigma_deg)^2``.

Derivative-free (a bounded compass search, :func:`_pattern_search`), from the
registered pose. Frames as in
:mod:`r2s.geometry.prior_refine`: world points are ``x = R (s * (p - c)) + t`` for prior
points ``p`` and the prior's bounding-box centre ``c``; the result is a
:class:`r2s.geometry.prior_refine.RefinedPose`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
import open3d as o3d
import trimesh
from scipy import ndimage
from scipy.spatial.transform import Rotation

from r2s.geometry.camera import camera_center
from r2s.geometry.mask_edges import foreign_rim_pixels
from r2s.geometry.prior_refine import RefinedPose


@dataclass(frozen=True)
class SilhouetteFitOptions:
    """Settings of :func:`fit_prior_to_view` (see the module docstring for the terms).

    scale_bounds : bounds of the per-axis scale relative to the unscaled prior.
    scale_sigma : per-axis log-scale deviation from the registration's that costs 1 px^2.
    rotation_sigma_deg : turn from the registered rotation that costs 1 px^2 (ICP on the
        observed points gets the rotation right more often than a coarse silhouette).
    depth_tolerance_m : truncation of the depth residual.
    occlusion_margin_m : an observed depth this much in front of the prior hides it.
    distance_cap_px : cap of a silhouette pixel's distance cost.
    rest_contact_m : a registered bottom within this of the plane is pulled onto it.
    support_weight, others_weight, depth_weight : weights of those terms.
    max_rays : pixels ray cast per evaluation (a stride thins larger windows).
    window_pad_px : pixels around the mask and the registered prior's image.
    max_evaluations : the search's budget of cost evaluations.
    contact_samples : surface samples (besides the hull's vertices) tested against others.
    contact_normaliser : see the ``others`` term.
    """

    scale_bounds: tuple[float, float] = (0.82, 1.22)
    scale_sigma: float = 0.1
    rotation_sigma_deg: float = 4.0
    depth_tolerance_m: float = 0.01
    occlusion_margin_m: float = 0.01
    distance_cap_px: float = 10.0
    rest_contact_m: float = 0.02
    support_weight: float = 1.0
    others_weight: float = 1.0
    depth_weight: float = 1.0
    max_rays: int = 20000
    window_pad_px: int = 20
    max_evaluations: int = 400
    contact_samples: int = 300
    contact_normaliser: float = 5.0


@dataclass(frozen=True)
class InstanceView:
    """What the camera saw of one instance, cropped to a window (rows r0:r1, cols c0:c1,
    every ``stride``-th pixel).

    K : (3, 3); world_from_camera : (4, 4) OpenCV camera.
    rays : (h, w, 3) world ray directions of the window's pixels (camera z = 1).
    depth_m : (h, w) observed depth, NaN = none.
    own : (h, w) bool, the instance's mask; care : (h, w) bool, the mask pixels the prior
        must cover (own without bleed).
    other_mask : (h, w) bool, pixels of other instances' masks.
    outside_px : (h, w) distance (full-resolution pixels) to the nearest ``own`` pixel.
    outline_px : outline length of the mask (full-resolution pixels).
    """

    K: np.ndarray
    world_from_camera: np.ndarray
    rays: np.ndarray
    depth_m: np.ndarray
    own: np.ndarray
    care: np.ndarray
    other_mask: np.ndarray
    outside_px: np.ndarray
    window: tuple[int, int, int, int]
    stride: int
    outline_px: float


@dataclass(frozen=True)
class ViewScore:
    """Cost terms of one pose (px^2) and the silhouette IoU against ``own`` in the window
    (pixels hidden by nearer things left out)."""

    total: float
    silhouette: float
    depth: float
    support: float
    others: float
    scale: float
    iou: float


def instance_view(K: np.ndarray, world_from_camera: np.ndarray, depth_m: np.ndarray,
                  masks: np.ndarray, obj_id: int, extra_box: Optional[tuple] = None,
                  support: Optional[tuple[np.ndarray, np.ndarray]] = None,
                  options: SilhouetteFitOptions = SilhouetteFitOptions()) -> InstanceView:
    """Crop the view around instance ``obj_id`` (masks (H, W) int ids, depth (H, W) m).

    extra_box : (r0, r1, c0, c1) pixels the window must also hold (the prior's image).
    support : (point, unit normal) of the table: mask rim pixels on it are bleed.
    """
    own_full = np.asarray(masks) == obj_id
    rows, cols = np.nonzero(own_full)
    if len(rows) == 0:
        raise ValueError(f"instance {obj_id} has an empty mask")
    height, width = own_full.shape
    box = [rows.min(), rows.max() + 1, cols.min(), cols.max() + 1]
    if extra_box is not None:
        box = [min(box[0], extra_box[0]), max(box[1], extra_box[1]),
               min(box[2], extra_box[2]), max(box[3], extra_box[3])]
    pad = options.window_pad_px
    r0, r1 = max(int(box[0]) - pad, 0), min(int(box[1]) + pad, height)
    c0, c1 = max(int(box[2]) - pad, 0), min(int(box[3]) + pad, width)
    stride = max(1, int(np.ceil(np.sqrt((r1 - r0) * (c1 - c0) / options.max_rays))))
    depth = np.asarray(depth_m, dtype=np.float64)
    care_full = own_full & ~foreign_rim_pixels(depth, own_full)
    if support is not None:
        care_full &= ~_table_rim(depth, own_full, K, world_from_camera, support)
    sl = (slice(r0, r1, stride), slice(c0, c1, stride))
    v, u = np.mgrid[r0:r1:stride, c0:c1:stride].astype(np.float64)
    d_cam = np.stack([u, v, np.ones_like(u)], axis=-1) @ np.linalg.inv(K).T
    rays = d_cam @ np.asarray(world_from_camera, dtype=np.float64)[:3, :3].T
    outline = own_full & ~ndimage.binary_erosion(own_full, border_value=0)
    return InstanceView(K=np.asarray(K, np.float64),
                        world_from_camera=np.asarray(world_from_camera, np.float64),
                        rays=rays, depth_m=depth[sl], own=own_full[sl], care=care_full[sl],
                        other_mask=(np.asarray(masks) > 0)[sl] & ~own_full[sl],
                        outside_px=ndimage.distance_transform_edt(~own_full[sl]) * stride,
                        window=(r0, r1, c0, c1), stride=stride,
                        outline_px=float(max(outline.sum(), 1)))


def _table_rim(depth: np.ndarray, own: np.ndarray, K: np.ndarray, world_from_camera: np.ndarray,
               support: tuple[np.ndarray, np.ndarray], rim_px: int = 3,
               height_m: float = 0.003) -> np.ndarray:
    """(H, W) bool: mask rim pixels whose observed point lies on the table (bleed onto it)."""
    rim = own & ~ndimage.binary_erosion(own, iterations=rim_px, border_value=1)
    r, c = np.nonzero(rim & np.isfinite(depth) & (depth > 0))
    out = np.zeros(own.shape, dtype=bool)
    if len(r) == 0:
        return out
    z = depth[r, c]
    cam_pts = np.stack([c * z, r * z, z], axis=1) @ np.linalg.inv(K).T
    world = cam_pts @ world_from_camera[:3, :3].T + world_from_camera[:3, 3]
    h = (world - np.asarray(support[0])) @ np.asarray(support[1])
    out[r[h < height_m], c[h < height_m]] = True
    return out


class _Caster:
    """Ray casts the centred prior (vertices ``p - c``) through an :class:`InstanceView`."""

    def __init__(self, mesh: trimesh.Trimesh, centre: np.ndarray, view: InstanceView):
        tm = o3d.t.geometry.TriangleMesh()
        verts = np.asarray(mesh.vertices, dtype=np.float64) - centre
        tm.vertex.positions = o3d.core.Tensor(verts.astype(np.float32))
        tm.triangle.indices = o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.int32))
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(tm)
        self.origin = camera_center(view.world_from_camera)
        self.rays = view.rays.reshape(-1, 3)
        self.shape = view.rays.shape[:2]
        self.buffer = np.empty((len(self.rays), 6), dtype=np.float32)

    def depth(self, R: np.ndarray, t: np.ndarray, s: np.ndarray) -> np.ndarray:
        """(h, w) camera depth of the prior posed by (R, t, s), NaN where missed."""
        A = (R / s[None, :]).T  # object-from-world linear part: diag(1/s) R^T
        self.buffer[:, :3] = A @ (self.origin - t)
        np.matmul(self.rays, A.T, out=self.buffer[:, 3:], casting="same_kind")
        t_hit = self.scene.cast_rays(o3d.core.Tensor.from_numpy(self.buffer),
                                    nthreads=1)["t_hit"].numpy()
        return np.where(np.isfinite(t_hit), t_hit, np.nan).reshape(self.shape)


def _silhouette_cost(model_depth: np.ndarray, view: InstanceView, cap_px: float,
                     occlusion_m: float) -> tuple[float, float, np.ndarray]:
    """(silhouette cost px^2, IoU, hit mask) of a rendered depth against the view."""
    hit = np.isfinite(model_depth)
    obs = view.depth_m
    valid = np.isfinite(obs) & (obs > 0)
    with np.errstate(invalid="ignore"):
        hidden = valid & (obs < model_depth - occlusion_m)
    hidden |= ~valid & view.other_mask
    false_pos = hit & ~view.own & ~hidden
    missed = view.care & ~hit
    st = view.stride
    cost = 0.0
    if false_pos.any():
        cost += float(np.minimum(view.outside_px[false_pos], cap_px).sum())
    if missed.any():
        d_hit = ndimage.distance_transform_edt(~hit) * st if hit.any() else None
        cost += float(missed.sum()) * cap_px if d_hit is None else float(
            np.minimum(d_hit[missed], cap_px).sum())
    cost *= st * st / view.outline_px
    shown = hit & ~hidden
    union = int((shown | view.own).sum())
    iou = float((shown & view.own).sum()) / union if union else 0.0
    return cost, iou, hit


def _depth_cost(model_depth: np.ndarray, view: InstanceView, hit: np.ndarray,
                tol_m: float) -> float:
    """Mean squared depth residual (px at the observed depth) over covered mask pixels."""
    obs = view.depth_m
    use = hit & view.care & np.isfinite(obs) & (obs > 0)
    if not use.any():
        return 0.0
    f = float(view.K[0, 0])
    dz = np.minimum(np.abs(model_depth[use] - obs[use]), tol_m)
    return float(np.mean((dz * f / obs[use]) ** 2))


@dataclass(frozen=True)
class ViewFit:
    """Result of :func:`fit_prior_to_view`: the pose, the scores before and after, whether
    the bottom was pulled onto the support, the evaluations used."""

    pose: RefinedPose
    before: ViewScore
    after: ViewScore
    resting: bool
    evaluations: int


class _Problem:
    """The cost of a parameter vector x (9,), relative to the start: the rotation vector
    (about the centre) times the prior's radius (m), then the moves (m) of the prior's
    three lower and three upper bounding-box faces along its own axes. Moving a face
    leaves the opposite one in place, so translation and scale are not entangled."""

    def __init__(self, mesh: trimesh.Trimesh, pose: RefinedPose, view: InstanceView,
                 support: Optional[tuple[np.ndarray, np.ndarray]],
                 others: Sequence["Obstacle"], o: SilhouetteFitOptions):
        self.o, self.view, self.support, self.others = o, view, support, list(others)
        self.centre = np.asarray(pose.centre, np.float64)
        self.caster = _Caster(mesh, self.centre, view)
        self.R0 = np.asarray(pose.world_from_object, np.float64)[:3, :3].copy()
        self.t0 = (np.asarray(pose.world_from_object, np.float64)[:3, 3]
                   + self.R0 @ (pose.axis_scale * self.centre))
        self.s0 = np.asarray(pose.axis_scale, np.float64).copy()
        verts = np.asarray(mesh.vertices, np.float64)
        self.half = np.maximum(0.5 * (verts.max(axis=0) - verts.min(axis=0)), 1e-6)
        try:
            hull = mesh.convex_hull.vertices
        except Exception:  # a degenerate prior: its vertices do
            hull = mesh.vertices
        self.hull = np.asarray(hull, np.float64) - self.centre
        surface, _ = trimesh.sample.sample_surface(mesh, o.contact_samples, seed=0)
        self.samples = np.concatenate([self.hull, np.asarray(surface) - self.centre])
        self.radius = float(np.linalg.norm(self.half * self.s0))
        self.pixel_m = float(np.nanmedian(view.depth_m[view.own])
                             if np.isfinite(view.depth_m[view.own]).any()
                             else np.linalg.norm(self.t0 - camera_center(view.world_from_camera))
                             ) / float(view.K[0, 0])
        self.resting = False
        if support is not None:
            self.resting = abs(self._bottom(self.R0, self.t0, self.s0)) < o.rest_contact_m
        self.evaluations = 0

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        R = Rotation.from_rotvec(x[:3] / self.radius).as_matrix() @ self.R0
        lower, upper = x[3:6], x[6:9]
        half = self.s0 * self.half + 0.5 * (upper - lower)
        s = np.clip(half / self.half, *self.o.scale_bounds)
        return R, self.t0 + R @ (0.5 * (lower + upper)), s

    def _bottom(self, R: np.ndarray, t: np.ndarray, s: np.ndarray) -> float:
        p0, n0 = self.support
        return float((((self.hull * s) @ R.T + t - p0) @ n0).min())

    def _others_cost(self, R: np.ndarray, t: np.ndarray, s: np.ndarray) -> float:
        if not self.others:
            return 0.0
        pts = (self.samples * s) @ R.T + t
        depth = np.zeros(len(self.samples))
        for other in self.others:
            depth = np.maximum(depth, other.penetration_m(pts))
        return float(np.sum((depth / self.pixel_m) ** 2)) / self.o.contact_normaliser

    def score(self, x: np.ndarray) -> ViewScore:
        o = self.o
        R, t, s = self.unpack(x)
        model_depth = self.caster.depth(R, t, s)
        sil, iou, hit = _silhouette_cost(model_depth, self.view, o.distance_cap_px,
                                         o.occlusion_margin_m)
        dep = o.depth_weight * _depth_cost(model_depth, self.view, hit, o.depth_tolerance_m)
        sup = 0.0
        if self.support is not None:
            h = self._bottom(R, t, s)
            if self.resting or h < 0:
                sup = o.support_weight * (h / self.pixel_m) ** 2
        oth = o.others_weight * self._others_cost(R, t, s)
        sc = float(np.sum((np.log(s / self.s0) / o.scale_sigma) ** 2))
        sc += float(np.degrees(np.linalg.norm(x[:3]) / self.radius) / o.rotation_sigma_deg) ** 2
        return ViewScore(total=sil + dep + sup + oth + sc, silhouette=sil, depth=dep,
                         support=sup, others=oth, scale=sc, iou=iou)

    def __call__(self, x: np.ndarray) -> float:
        self.evaluations += 1
        return self.score(x).total

    def bounds(self) -> list[tuple[float, float]]:
        rot = [(-0.35 * self.radius, 0.35 * self.radius)] * 3
        reach = self.o.scale_bounds[1] * self.half + 0.03
        faces = [(-float(r), float(r)) for r in reach]
        return rot + faces + faces

    def pose(self, x: np.ndarray) -> RefinedPose:
        R, t, s = self.unpack(x)
        out = np.eye(4)
        out[:3, :3] = R
        out[:3, 3] = t - R @ (s * self.centre)
        return RefinedPose(world_from_object=out, axis_scale=s, centre=self.centre,
                           on_support=self.resting)


def _pattern_search(cost, x0: np.ndarray, bounds: list[tuple[float, float]],
                    max_evaluations: int, step_m: float = 0.004, min_step_m: float = 0.00025
                    ) -> np.ndarray:
    """Compass search: try +-step along each coordinate, keep going while a move lowers the
    cost, halve the step when a sweep finds nothing (robust on a cost that is piecewise
    constant at the pixel scale, unlike line searches). Returns the best x found."""
    lo = np.array([b[0] for b in bounds])
    hi = np.array([b[1] for b in bounds])
    x, fx, used = np.array(x0, dtype=np.float64), cost(x0), 1
    step = step_m
    while step >= min_step_m and used < max_evaluations:
        improved = False
        for i in range(len(x)):
            for sign in (1.0, -1.0):
                while used < max_evaluations:
                    trial = x.copy()
                    trial[i] = np.clip(trial[i] + sign * step, lo[i], hi[i])
                    if trial[i] == x[i]:
                        break
                    ft = cost(trial)
                    used += 1
                    if not ft < fx:
                        break
                    x, fx, improved = trial, ft, True
        if not improved:
            step /= 2.0
    return x


def fit_prior_to_view(mesh: trimesh.Trimesh, start: RefinedPose, view: InstanceView,
                      support: Optional[tuple[np.ndarray, np.ndarray]] = None,
                      others: Sequence["Obstacle"] = (),
                      options: SilhouetteFitOptions = SilhouetteFitOptions()) -> ViewFit:
    """Fit pose and per-axis scale of a prior to one instance's view (module docstring).

    mesh : the prior, its own frame (unscaled); start : its registered pose and scale.
    view : :func:`instance_view` of the instance; support : (point, unit normal) or None.
    others : :func:`obstacle` of objects already placed: the prior is kept out of them.
    The start is returned unchanged when the fit does not lower the cost.
    """
    problem = _Problem(mesh, start, view, support, others, options)
    x0 = np.zeros(9)
    before = problem.score(x0)
    x = _pattern_search(problem, x0, problem.bounds(), options.max_evaluations)
    after = problem.score(x)
    if not after.total < before.total:
        x, after = x0, before
    return ViewFit(pose=problem.pose(x), before=before, after=after,
                   resting=problem.resting, evaluations=problem.evaluations)


@dataclass(frozen=True)
class Obstacle:
    """A world-frame mesh other priors are kept out of: its Open3D scene and its
    axis-aligned box ``lo``, ``hi`` (3,) (points outside it are not queried)."""

    scene: o3d.t.geometry.RaycastingScene
    lo: np.ndarray
    hi: np.ndarray

    def penetration_m(self, points_world: np.ndarray) -> np.ndarray:
        """(N,) depth (m) of each point inside the mesh, 0 outside."""
        pts = np.asarray(points_world, dtype=np.float64)
        out = np.zeros(len(pts))
        near = np.all((pts > self.lo) & (pts < self.hi), axis=1)
        if near.any():
            query = o3d.core.Tensor(pts[near].astype(np.float32))
            sd = self.scene.compute_signed_distance(query, nthreads=1).numpy()
            out[near] = np.maximum(-sd, 0.0)
        return out


def obstacle(mesh_world: trimesh.Trimesh) -> Obstacle:
    """The :class:`Obstacle` of a world-frame mesh (for ``others`` of
    :func:`fit_prior_to_view`)."""
    tm = o3d.t.geometry.TriangleMesh()
    tm.vertex.positions = o3d.core.Tensor(np.asarray(mesh_world.vertices, dtype=np.float32))
    tm.triangle.indices = o3d.core.Tensor(np.asarray(mesh_world.faces, dtype=np.int32))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(tm)
    bounds = np.asarray(mesh_world.bounds, dtype=np.float64)
    return Obstacle(scene=scene, lo=bounds[0], hi=bounds[1])


def image_box(mesh_world: trimesh.Trimesh, K: np.ndarray, world_from_camera: np.ndarray
              ) -> tuple[int, int, int, int]:
    """(r0, r1, c0, c1) pixel box of a world-frame mesh's vertices in the image."""
    cam = (np.asarray(mesh_world.vertices) - world_from_camera[:3, 3]) @ world_from_camera[:3, :3]
    z = np.maximum(cam[:, 2], 1e-6)
    uv = (cam[:, :2] / z[:, None]) * np.diag(K)[:2] + K[:2, 2]
    return (int(np.floor(uv[:, 1].min())), int(np.ceil(uv[:, 1].max())) + 1,
            int(np.floor(uv[:, 0].min())), int(np.ceil(uv[:, 0].max())) + 1)


def _posed(prior: trimesh.Trimesh, pose: RefinedPose) -> trimesh.Trimesh:
    mesh, world_from_object = pose.object_mesh(prior)
    out = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    out.apply_transform(world_from_object)
    return out


def penetration_m(mesh_world: trimesh.Trimesh, others: Sequence[Obstacle],
                  samples: int = 600) -> float:
    """Deepest penetration (m) of a world-frame mesh's vertices and surface samples into
    the other objects (0 when none)."""
    if not others:
        return 0.0
    surface, _ = trimesh.sample.sample_surface(mesh_world, samples, seed=0)
    pts = np.concatenate([np.asarray(mesh_world.vertices), np.asarray(surface)])
    return max(float(other.penetration_m(pts).max()) for other in others)


def fit_priors_to_view(priors: dict[int, tuple[trimesh.Trimesh, RefinedPose]],
                       fixed_world: dict[int, trimesh.Trimesh], K: np.ndarray,
                       world_from_camera: np.ndarray, depth_m: np.ndarray, masks: np.ndarray,
                       support: Optional[tuple[np.ndarray, np.ndarray]],
                       options: SilhouetteFitOptions = SilhouetteFitOptions(),
                       separation_m: float = 0.002) -> dict[int, ViewFit]:
    """Fit every registered prior to its view, then keep them out of each other.

    priors : id -> (prior mesh in its own frame, registered pose); fixed_world : id ->
    world-frame mesh of the objects that are not fitted (completed ones). First each prior
    alone (:func:`fit_prior_to_view`); then each prior that reaches more than
    ``separation_m`` into another object is fitted again from there with every other
    object as an obstacle (the ``others`` term), in id order.
    """
    fits: dict[int, ViewFit] = {}
    for obj_id, (prior, pose) in priors.items():
        view = instance_view(K, world_from_camera, depth_m, masks, obj_id,
                             extra_box=image_box(_posed(prior, pose), K, world_from_camera),
                             support=support, options=options)
        fits[obj_id] = fit_prior_to_view(prior, pose, view, support, options=options)
    world = dict(fixed_world)
    world.update({i: _posed(priors[i][0], f.pose) for i, f in fits.items()})
    scenes = {i: obstacle(m) for i, m in world.items()}
    for obj_id, (prior, _) in priors.items():
        others = [scenes[j] for j in scenes if j != obj_id]
        if penetration_m(world[obj_id], others) <= separation_m:
            continue
        start = fits[obj_id].pose
        view = instance_view(K, world_from_camera, depth_m, masks, obj_id,
                             extra_box=image_box(world[obj_id], K, world_from_camera),
                             support=support, options=options)
        refit = fit_prior_to_view(prior, start, view, support, others, options)
        fits[obj_id] = ViewFit(pose=refit.pose, before=fits[obj_id].before, after=refit.after,
                               resting=refit.resting,
                               evaluations=fits[obj_id].evaluations + refit.evaluations)
        world[obj_id] = _posed(prior, refit.pose)
        scenes[obj_id] = obstacle(world[obj_id])
    return fits
