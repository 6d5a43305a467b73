"""Register a complete prior mesh to the partial observed points of its instance.

One RGB-D view sees only the front of an object, so correspondences go from each observed
point to the model surface (observed -> model), never the other way, and only to the part
of the model that faces the camera at the current pose. The error is point-to-plane
(model normals), weighted by a Tukey loss whose width shrinks over a schedule of
correspondence distances, and the worst residuals are trimmed (mixed pixels at silhouette
edges, a prior whose shape is a little off). An isotropic scale correction within bounds
can be estimated with the pose: single-image priors carry a few per cent of scale error.

Without an initial pose, a global search refines a set of rotation hypotheses (each model
axis up, yaws about the support normal) with a short ICP each and keeps the best.

The estimated transform maps the *scaled* prior to the world::

    x_world = world_from_object @ (scale * p_prior)
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from r2s.geometry.camera import transform_points


@dataclass(frozen=True)
class IcpOptions:
    """Settings of :func:`register_prior`.

    Attributes
    ----------
    max_correspondence_m : correspondence-distance schedule, coarse to fine (metres); the
        Tukey loss width follows it.
    iterations_per_level : Gauss-Newton iterations per schedule level.
    trim_fraction : fraction of the largest residuals dropped every iteration.
    estimate_scale : also estimate an isotropic scale of the prior.
    scale_bounds : allowed scale range when ``estimate_scale``.
    scale_prior_weight : ridge weight pulling the scale towards 1 (per point, in the
        linearised system; 0 = none).
    inlier_m : distance under which an observed point counts as explained (fitness, rmse).
    model_samples : number of points sampled on the model surface.
    max_observed_points : observed points are randomly subsampled to at most this many.
    use_visibility : only match model points that face the viewpoint (needs ``viewpoint``).
    global_fallback_fitness : with an initial pose, run the global search too when the
        local result explains fewer observed points than this.
    global_yaw_steps : yaw hypotheses per "up" axis in the global search.
    global_keep : hypotheses refined with the full schedule after the coarse pass.
    seed : random seed (sampling).
    """

    max_correspondence_m: tuple[float, ...] = (0.04, 0.02, 0.01, 0.005)
    iterations_per_level: int = 15
    trim_fraction: float = 0.1
    estimate_scale: bool = False
    scale_bounds: tuple[float, float] = (0.85, 1.15)
    scale_prior_weight: float = 0.0
    inlier_m: float = 0.005
    model_samples: int = 20000
    max_observed_points: int = 3000
    use_visibility: bool = True
    global_fallback_fitness: float = 0.5
    global_yaw_steps: int = 12
    global_keep: int = 3
    seed: int = 0


@dataclass(frozen=True)
class RegistrationResult:
    """The registered pose of a prior.

    Attributes
    ----------
    world_from_object : (4, 4) rigid; maps the scaled prior frame to the world.
    scale : isotropic scale applied to the prior's vertices (1.0 when not estimated).
    fitness : fraction of observed points within ``inlier_m`` of the model surface.
    rmse_m : RMS distance of those inlier points to the model surface, world metres.
    """

    world_from_object: np.ndarray
    scale: float
    fitness: float
    rmse_m: float

    def world_from_prior_points(self, points_prior: np.ndarray) -> np.ndarray:
        """(N, 3) world positions of (N, 3) unscaled prior-frame points."""
        return transform_points(self.world_from_object, self.scale * np.asarray(points_prior))


@dataclass(frozen=True)
class _Model:
    """Dense oriented samples of the prior surface, prior frame (unscaled)."""

    points: np.ndarray  # (M, 3)
    normals: np.ndarray  # (M, 3) unit
    tree: cKDTree
    center: np.ndarray  # (3,)
    radius: float


@dataclass
class _Similarity:
    """``y = c * R @ x + t``: world -> prior frame (inverse of the registered pose)."""

    c: float
    R: np.ndarray
    t: np.ndarray

    def apply(self, x: np.ndarray) -> np.ndarray:
        return self.c * (x @ self.R.T) + self.t

    def result(self) -> tuple[np.ndarray, float]:
        """world_from_object (rigid, on scaled prior points) and the scale."""
        scale = 1.0 / self.c
        out = np.eye(4)
        out[:3, :3] = self.R.T
        out[:3, 3] = -scale * (self.R.T @ self.t)
        return out, scale

    @staticmethod
    def from_pose(world_from_object: np.ndarray, scale: float) -> "_Similarity":
        rot = np.asarray(world_from_object, dtype=np.float64)[:3, :3]
        trans = np.asarray(world_from_object, dtype=np.float64)[:3, 3]
        c = 1.0 / scale
        return _Similarity(c=c, R=rot.T.copy(), t=-c * (rot.T @ trans))


def _sample_model(mesh: trimesh.Trimesh, count: int, seed: int) -> _Model:
    points, face_idx = trimesh.sample.sample_surface(mesh, count, seed=seed)
    normals = np.asarray(mesh.face_normals)[face_idx]
    keep = np.all(np.isfinite(normals), axis=1) & (np.linalg.norm(normals, axis=1) > 0.5)
    points, normals = np.asarray(points)[keep], normals[keep]
    lo, hi = points.min(axis=0), points.max(axis=0)
    center = 0.5 * (lo + hi)
    return _Model(points=points, normals=normals, tree=cKDTree(points), center=center,
                  radius=float(0.5 * np.linalg.norm(hi - lo)))


def _correspond(model: _Model, y: np.ndarray, viewpoint_obj: np.ndarray | None,
                max_dist: float = np.inf, k: int = 8
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest (front-facing) model sample within ``max_dist`` of each point y (prior frame).

    Returns the sample index (-1 when none), the Euclidean distance (inf when none) and the
    signed point-to-plane residual (inf when none).
    """
    n_model = len(model.points)
    dist, idx = model.tree.query(y, k=k if viewpoint_obj is not None else 1,
                                 distance_upper_bound=max_dist)
    if viewpoint_obj is None:
        idx, dist = idx.reshape(-1), dist.reshape(-1)
        idx = np.where(idx < n_model, idx, -1)
    else:
        found = idx < n_model
        idx_safe = np.where(found, idx, 0)
        m = model.points[idx_safe]  # (N, k, 3)
        facing = found & (np.einsum("nkj,nkj->nk", model.normals[idx_safe], viewpoint_obj - m) > 0)
        idx = idx_safe
        first = np.argmax(facing, axis=1)
        rows = np.arange(len(y))
        ok = facing[rows, first]
        idx = np.where(ok, idx[rows, first], -1)
        dist = np.where(ok, dist[rows, first], np.inf)
    safe = np.maximum(idx, 0)
    res = np.einsum("nj,nj->n", y - model.points[safe], model.normals[safe])
    res[idx < 0] = np.inf
    return idx, dist, res


def _icp(model: _Model, obs: np.ndarray, sim: _Similarity, viewpoint: np.ndarray | None,
         opts: IcpOptions, schedule: tuple[float, ...], iterations: int) -> _Similarity:
    """Robust point-to-plane ICP (observed -> model) with optional scale; returns the fit."""
    sim = _Similarity(sim.c, sim.R.copy(), sim.t.copy())
    est_scale = opts.estimate_scale
    c_lo, c_hi = 1.0 / opts.scale_bounds[1], 1.0 / opts.scale_bounds[0]
    npar = 7 if est_scale else 6
    for level_m in schedule:
        for _ in range(iterations):
            y = sim.apply(obs)
            vp = None
            if viewpoint is not None and opts.use_visibility:
                vp = sim.apply(viewpoint[None])[0]
            # distances and residuals are in the prior frame; level_m is in the world
            gate = level_m * sim.c
            idx, dist, res = _correspond(model, y, vp, max_dist=gate)
            use = (idx >= 0) & (dist < gate)
            if use.sum() < max(npar * 2, 10):
                break
            if opts.trim_fraction > 0:
                cut = np.quantile(np.abs(res[use]), 1.0 - opts.trim_fraction)
                use &= np.abs(res) <= max(cut, 1e-9)
            r = res[use]
            n = model.normals[idx[use]]
            q = y[use] - model.center
            w = np.clip(1.0 - (r / gate) ** 2, 0.0, None) ** 2
            cols = [np.cross(q, n), n]
            if est_scale:
                cols.append(np.einsum("nj,nj->n", q, n)[:, None])
            J = np.concatenate(cols, axis=1)
            A = J.T @ (J * w[:, None])
            b = -J.T @ (w * r)
            A += np.eye(npar) * 1e-6 * max(np.trace(A) / npar, 1e-12)
            if est_scale and opts.scale_prior_weight > 0:
                A[6, 6] += opts.scale_prior_weight * w.sum() * model.radius ** 2
                b[6] -= opts.scale_prior_weight * w.sum() * model.radius ** 2 * (sim.c - 1.0)
            try:
                delta = np.linalg.solve(A, b)
            except np.linalg.LinAlgError:
                break
            rot_inc = Rotation.from_rotvec(delta[:3]).as_matrix()
            dc = 1.0 + (delta[6] if est_scale else 0.0)
            new_c = float(np.clip(sim.c * dc, c_lo, c_hi))
            dc = new_c / sim.c
            # y' = dc * R_inc (y - center) + center + dt
            R_new = rot_inc @ sim.R
            t_new = dc * (rot_inc @ (sim.t - model.center)) + model.center + delta[3:6]
            sim = _Similarity(new_c, R_new, t_new)
            if np.linalg.norm(delta[:3]) < 1e-6 and np.linalg.norm(delta[3:6]) < 1e-7 * sim.c:
                break
    return sim


def _evaluate(model: _Model, obs: np.ndarray, sim: _Similarity, viewpoint: np.ndarray | None,
              opts: IcpOptions) -> tuple[float, float, float]:
    """(fitness, rmse_m, truncated score) of a fit; the score is lower-better."""
    y = sim.apply(obs)
    vp = None
    if viewpoint is not None and opts.use_visibility:
        vp = sim.apply(viewpoint[None])[0]
    idx, dist, res = _correspond(model, y, vp, max_dist=3 * opts.inlier_m * sim.c)
    # point-to-plane where the nearest sample is close, Euclidean otherwise; world metres
    d = np.where(dist < 3 * opts.inlier_m * sim.c, np.abs(res), dist) / sim.c
    d[idx < 0] = np.inf
    inl = d < opts.inlier_m
    fitness = float(inl.mean()) if len(d) else 0.0
    rmse = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else float("inf")
    tau = 2.0 * opts.inlier_m
    score = float(np.mean(np.minimum(d, tau) ** 2))
    return fitness, rmse, score


def _subsample(points: np.ndarray, count: int, seed: int) -> np.ndarray:
    if len(points) <= count:
        return points
    rng = np.random.default_rng(seed)
    return points[np.sort(rng.choice(len(points), size=count, replace=False))]


def rotation_hypotheses(model_axes: np.ndarray, up: np.ndarray, yaw_steps: int) -> np.ndarray:
    """(K, 3, 3) world_from_prior rotations putting each of ``±model_axes`` along ``up``,
    at ``yaw_steps`` yaws about ``up``.

    model_axes : (A, 3) unit directions in the prior frame (duplicates within 10 deg are
    dropped).
    """
    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    cands: list[np.ndarray] = []
    for a in np.asarray(model_axes, dtype=np.float64):
        for s in (1.0, -1.0):
            v = s * a / np.linalg.norm(a)
            if all(v @ c < np.cos(np.radians(10)) for c in cands):
                cands.append(v)
    out = []
    for v in cands:
        align, _ = Rotation.align_vectors(up[None], v[None])
        for k in range(yaw_steps):
            yaw = Rotation.from_rotvec(up * (2 * np.pi * k / yaw_steps))
            out.append((yaw * align).as_matrix())
    return np.asarray(out)


def _global_candidates(model: _Model, mesh: trimesh.Trimesh, obs: np.ndarray,
                       viewpoint: np.ndarray | None, up: np.ndarray,
                       opts: IcpOptions) -> list[_Similarity]:
    """Coarse ICP from every rotation hypothesis; the best ``global_keep`` fits."""
    axes = [np.eye(3)]
    try:
        axes.append(np.asarray(mesh.bounding_box_oriented.primitive.transform)[:3, :3].T)
    except Exception:  # degenerate meshes have no oriented box; the frame axes suffice
        pass
    rots = rotation_hypotheses(np.concatenate(axes), up, opts.global_yaw_steps)
    centroid = obs.mean(axis=0)
    view = centroid - viewpoint if viewpoint is not None else -np.asarray(up, dtype=np.float64)
    view = view / np.linalg.norm(view)
    coarse = replace(opts, estimate_scale=False, trim_fraction=max(opts.trim_fraction, 0.2))
    sims = []
    for rot in rots:
        # model centre behind the visible surface by half the model radius
        centre_w = centroid + view * 0.5 * model.radius
        world_from_obj = np.eye(4)
        world_from_obj[:3, :3] = rot
        world_from_obj[:3, 3] = centre_w - rot @ model.center
        sims.append(_Similarity.from_pose(world_from_obj, 1.0))
    # successive halving: short ICPs on few points, the better half goes on with more
    levels = opts.max_correspondence_m[:2] or (0.02,)
    rounds = [(150, levels[0], 6), (300, levels[-1], 8), (600, levels[-1], 8)]
    for round_i, (n_points, level_m, iters) in enumerate(rounds):
        sub = _subsample(obs, n_points, opts.seed + round_i)
        sims = [_icp(model, sub, s, viewpoint, coarse, (level_m,), iters) for s in sims]
        scores = [_evaluate(model, sub, s, viewpoint, opts)[2] for s in sims]
        order = np.argsort(scores, kind="stable")
        keep = max(opts.global_keep, len(sims) // 4) if round_i < len(rounds) - 1 \
            else opts.global_keep
        sims = [sims[i] for i in order[:max(keep, 1)]]
    return sims


def register_prior(mesh: trimesh.Trimesh, observed_points: np.ndarray,
                   world_from_prior: np.ndarray | None = None,
                   viewpoint: np.ndarray | None = None,
                   up: np.ndarray | None = None,
                   options: IcpOptions = IcpOptions()) -> RegistrationResult:
    """Register a complete prior mesh to the observed points of its instance.

    Parameters
    ----------
    mesh : the prior, in its own frame, metres.
    observed_points : (N, 3) world points of the instance (one partial view).
    world_from_prior : (4, 4) initial pose, or None for a global search.
    viewpoint : (3,) camera centre, world frame; enables visibility-aware matching.
    up : (3,) world up (the support normal) for the global search's hypotheses; default +z.
    options : :class:`IcpOptions`.

    Returns
    -------
    :class:`RegistrationResult`.
    """
    obs_all = np.asarray(observed_points, dtype=np.float64).reshape(-1, 3)
    obs_all = obs_all[np.all(np.isfinite(obs_all), axis=1)]
    if len(obs_all) < 10:
        raise ValueError("registration needs at least 10 observed points")
    obs = _subsample(obs_all, options.max_observed_points, options.seed)
    model = _sample_model(mesh, options.model_samples, options.seed)
    vp = None if viewpoint is None else np.asarray(viewpoint, dtype=np.float64)
    up_vec = np.asarray(up if up is not None else (0.0, 0.0, 1.0), dtype=np.float64)
    sched, iters = options.max_correspondence_m, options.iterations_per_level

    starts: list[_Similarity] = []
    if world_from_prior is not None:
        starts.append(_Similarity.from_pose(world_from_prior, 1.0))
    best = None
    for start in starts:
        sim = _icp(model, obs, start, vp, options, sched, iters)
        ev = _evaluate(model, obs, sim, vp, options)
        if best is None or ev[2] < best[0][2]:
            best = (ev, sim)
    if best is None or best[0][0] < options.global_fallback_fitness:
        for start in _global_candidates(model, mesh, obs, vp, up_vec, options):
            sim = _icp(model, obs, start, vp, options, sched, iters)
            ev = _evaluate(model, obs, sim, vp, options)
            if best is None or ev[2] < best[0][2]:
                best = (ev, sim)
    assert best is not None
    sim = best[1]
    fitness, rmse, _ = _evaluate(model, obs_all if len(obs_all) <= 20000 else
                                 _subsample(obs_all, 20000, options.seed), sim, vp, options)
    world_from_object, scale = sim.result()
    return RegistrationResult(world_from_object=world_from_object, scale=scale,
                              fitness=fitness, rmse_m=rmse)
