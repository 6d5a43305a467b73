"""Register a complete prior mesh to the partial observed points of its instance.

One RGB-D view sees only the front of an object, so correspondences go from each observed
point to the model surface (observed -> model), never the other way, and only to the part
of the model that faces the camera at the current pose. The error is point-to-plane
(model normals), weighted by a Tukey loss whose width shrinks over a schedule of
correspondence distances, and the worst residuals are trimmed (mixed pixels at silhouette
edges, a prior whose shape is a little off). Two more terms pin what point-to-plane leaves
free: observed points lying past the edge of the face they match keep their tangential
residual, and model points the camera sees past (outside the mask, in front of the
observed surface) are pulled back into the mask (:mod:`r2s.geometry.free_space`). An
isotropic scale correction within bounds is estimated with the pose: single-image priors
carry a few per cent of scale error.

From a given pose, the same pose turned about the support normal is tried too (single-
image estimates often get the yaw wrong). Without a pose, or when the result explains
too few points, a global search refines rotation hypotheses (each model axis up, yaws
about the support normal) by successive halving and keeps the best.

The estimated transform maps the *scaled* prior to the world::

    x_world = world_from_object @ (scale * p_prior)
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from r2s.geometry.camera import transform_points
from r2s.geometry.free_space import ViewConstraint, free_space_violations

_MATCHER_CACHE_SIZE = 64
"""Matchers (facing sample sets and their trees) kept per model."""


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
    local_yaw_steps : with an initial pose, also try it turned about the up axis by
        multiples of ``360 / local_yaw_steps`` degrees (1 = only the given pose).
    local_switch_ratio : a turned start must score below this fraction of the given
        pose's score (and below it by ``(inlier_m / 5)^2``) to replace it: symmetric
        shapes score alike at several yaws.
    global_yaw_steps : yaw hypotheses per "up" axis in the global search.
    global_keep : hypotheses refined with the full schedule after the coarse pass.
    edge_weight : weight of the tangential residual of observed points that lie past the
        edge of the model face they match (point-to-plane alone lets a model shrink or
        slide under them); used on the last schedule level only, as it narrows the
        basin of convergence.
    silhouette_weight : weight of the free-space term (with a :class:`ViewConstraint`): model
        points that project onto pixels where the camera sees *past* them, outside the
        instance mask, are pulled to the nearest mask pixel. 1 weighs it like the data
        term when every tested model point violates it.
    free_space_tolerance_m : how far behind a model point the observed surface must be for
        the pixel to count as seen-through.
    silhouette_samples : model points tested against the silhouette per iteration.
    rotation_prior_weight : ridge pulling the rotation towards the initial one (symmetric
        shapes leave rotation unconstrained; 0 = none).
    seed : random seed (sampling).
    """

    max_correspondence_m: tuple[float, ...] = (0.04, 0.02, 0.01, 0.005)
    iterations_per_level: int = 15
    trim_fraction: float = 0.1
    estimate_scale: bool = True
    scale_bounds: tuple[float, float] = (0.85, 1.15)
    scale_prior_weight: float = 0.0
    inlier_m: float = 0.005
    model_samples: int = 20000
    max_observed_points: int = 3000
    use_visibility: bool = True
    global_fallback_fitness: float = 0.5
    local_yaw_steps: int = 8
    local_switch_ratio: float = 0.7
    global_yaw_steps: int = 12
    global_keep: int = 3
    edge_weight: float = 1.0
    silhouette_weight: float = 1.0
    free_space_tolerance_m: float = 0.01
    silhouette_samples: int = 3000
    rotation_prior_weight: float = 0.0
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
    silhouette_idx: np.ndarray  # samples tested against the silhouette
    spacing: float  # typical distance between neighbouring samples
    matchers: dict = field(default_factory=dict, repr=False, compare=False)
    """Matchers by facing mask (bytes), filled by :func:`_matcher`."""


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


def _sample_model(mesh: trimesh.Trimesh, count: int, seed: int, silhouette_count: int
                  ) -> _Model:
    points, face_idx = trimesh.sample.sample_surface(mesh, count, seed=seed)
    normals = np.asarray(mesh.face_normals)[face_idx]
    keep = np.all(np.isfinite(normals), axis=1) & (np.linalg.norm(normals, axis=1) > 0.5)
    points, normals = np.asarray(points)[keep], normals[keep]
    lo, hi = points.min(axis=0), points.max(axis=0)
    center = 0.5 * (lo + hi)
    rng = np.random.default_rng(seed)
    sil = np.sort(rng.choice(len(points), size=min(silhouette_count, len(points)),
                             replace=False))
    spacing = float(np.sqrt(max(mesh.area, 1e-12) / max(len(points), 1)))
    return _Model(points=points, normals=normals, tree=cKDTree(points), center=center,
                  radius=float(0.5 * np.linalg.norm(hi - lo)), silhouette_idx=sil,
                  spacing=spacing)


def _silhouette_targets(model: _Model, sim: "_Similarity", view: ViewConstraint,
                        tolerance_m: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Model samples the camera sees past and where they should go, prior frame.

    Returns (targets (V, 3), samples (V, 3), number of samples tested); see
    :func:`r2s.geometry.free_space.free_space_violations`.
    """
    m = model.points[model.silhouette_idx]
    world_from_object, scale = sim.result()
    xw = transform_points(world_from_object, scale * m)
    nw = model.normals[model.silhouette_idx] @ world_from_object[:3, :3].T
    viol, targets_w, tested = free_space_violations(view, xw, nw, tolerance_m)
    return sim.apply(targets_w), m[viol], tested


@dataclass(frozen=True)
class _Matcher:
    """Nearest-sample lookup restricted to the model samples that face the viewpoint."""

    tree: cKDTree
    index: np.ndarray  # subset position -> model sample index


def _matcher(model: _Model, viewpoint_obj: np.ndarray | None) -> _Matcher:
    """Samples whose normal faces ``viewpoint_obj`` (prior frame), or all when None.

    The visible side changes slowly while a pose is refined: the matcher of a set of
    samples met before is taken from ``model.matchers`` instead of building its tree
    again (the same points give the same tree and so the same matches)."""
    if viewpoint_obj is None:
        return _Matcher(model.tree, np.arange(len(model.points)))
    facing = np.einsum("nj,nj->n", model.normals, viewpoint_obj - model.points) > 0
    index = np.flatnonzero(facing)
    if len(index) < 3:
        return _Matcher(model.tree, np.arange(len(model.points)))
    key = facing.tobytes()
    found = model.matchers.get(key)
    if found is None:
        if len(model.matchers) >= _MATCHER_CACHE_SIZE:
            model.matchers.pop(next(iter(model.matchers)))
        found = model.matchers[key] = _Matcher(cKDTree(model.points[index]), index)
    return found


def _correspond(model: _Model, matcher: _Matcher, y: np.ndarray, max_dist: float = np.inf
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest matchable model sample within ``max_dist`` of each point y (prior frame).

    Returns the sample index (-1 when none), the Euclidean distance (inf when none) and the
    signed point-to-plane residual (inf when none).
    """
    dist, pos = matcher.tree.query(y, k=1, distance_upper_bound=max_dist)
    found = pos < len(matcher.index)
    idx = np.where(found, matcher.index[np.where(found, pos, 0)], -1)
    safe = np.maximum(idx, 0)
    res = np.einsum("nj,nj->n", y - model.points[safe], model.normals[safe])
    res[~found] = np.inf
    return idx, dist, res


def _add_point_rows(A: np.ndarray, b: np.ndarray, q: np.ndarray, r3: np.ndarray,
                    weights: np.ndarray, est_scale: bool) -> None:
    """Add weighted 3-D residuals ``r3`` (V, 3) of points at ``q`` (V, 3, relative to the
    pivot) to the normal equations ``A x = b`` in place."""
    npar = A.shape[0]
    J = np.zeros((len(q), 3, npar))
    # d(w x q)/dw = -[q]x
    J[:, 0, 1], J[:, 0, 2] = q[:, 2], -q[:, 1]
    J[:, 1, 0], J[:, 1, 2] = -q[:, 2], q[:, 0]
    J[:, 2, 0], J[:, 2, 1] = q[:, 1], -q[:, 0]
    J[:, :, 3:6] = np.eye(3)
    if est_scale:
        J[:, :, 6] = q
    A += np.einsum("vki,vkj,v->ij", J, J, weights)
    b -= np.einsum("vki,vk,v->i", J, r3, weights)


def _icp(model: _Model, obs: np.ndarray, sim: _Similarity, viewpoint: np.ndarray | None,
         view: ViewConstraint | None, opts: IcpOptions, schedule: tuple[float, ...],
         iterations: int) -> _Similarity:
    """Robust point-to-plane ICP (observed -> model) with optional scale and free-space
    term; returns the fit."""
    sim = _Similarity(sim.c, sim.R.copy(), sim.t.copy())
    R_start = sim.R.copy()
    est_scale = opts.estimate_scale
    c_lo, c_hi = 1.0 / opts.scale_bounds[1], 1.0 / opts.scale_bounds[0]
    npar = 7 if est_scale else 6
    for level_m in schedule:
        for it in range(iterations):
            y = sim.apply(obs)
            if it % 5 == 0:  # the visible side changes slowly: refresh it now and then
                vp = None
                if viewpoint is not None and opts.use_visibility:
                    vp = sim.apply(viewpoint[None])[0]
                matcher = _matcher(model, vp)
            # distances and residuals are in the prior frame; level_m is in the world
            gate = level_m * sim.c
            idx, dist, res = _correspond(model, matcher, y, max_dist=gate)
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
            if opts.edge_weight > 0 and level_m == schedule[-1]:
                # a point past the edge of the face it matches is off the model, though
                # its point-to-plane residual is 0 (a shrunk box would fit): give such
                # points their full 3-D residual
                r3 = y[use] - model.points[idx[use]]
                tangential = r3 - np.einsum("nj,nj->n", r3, n)[:, None] * n
                off = np.linalg.norm(tangential, axis=1) > 1.5 * model.spacing
                if off.any():
                    _add_point_rows(A, b, q[off], tangential[off],
                                    opts.edge_weight * w[off], est_scale)
            if view is not None and opts.silhouette_weight > 0:
                ty, tm, tested = _silhouette_targets(model, sim, view,
                                                     opts.free_space_tolerance_m)
                if len(ty):
                    r3 = ty - tm
                    rn = np.linalg.norm(r3, axis=1)
                    ws = opts.silhouette_weight * w.sum() / max(tested, 1)
                    ws = ws * np.minimum(1.0, gate / np.maximum(rn, 1e-12))
                    _add_point_rows(A, b, ty - model.center, r3, ws, est_scale)
            if opts.rotation_prior_weight > 0:
                lam = opts.rotation_prior_weight * w.sum() * model.radius ** 2
                dev = Rotation.from_matrix(sim.R @ R_start.T).as_rotvec()
                A[:3, :3] += lam * np.eye(3)
                b[:3] -= lam * dev
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
              view: ViewConstraint | None, opts: IcpOptions) -> tuple[float, float, float]:
    """(fitness, rmse_m, score) of a fit; the score (lower-better) is the mean truncated
    squared distance plus the fraction of silhouette violations at the truncation."""
    y = sim.apply(obs)
    vp = None
    if viewpoint is not None and opts.use_visibility:
        vp = sim.apply(viewpoint[None])[0]
    idx, dist, res = _correspond(model, _matcher(model, vp), y,
                                 max_dist=3 * opts.inlier_m * sim.c)
    # point-to-plane where the nearest sample is close, Euclidean otherwise; world metres
    d = np.where(dist < 3 * opts.inlier_m * sim.c, np.abs(res), dist) / sim.c
    d[idx < 0] = np.inf
    inl = d < opts.inlier_m
    fitness = float(inl.mean()) if len(d) else 0.0
    rmse = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else float("inf")
    tau = 2.0 * opts.inlier_m
    score = float(np.mean(np.minimum(d, tau) ** 2))
    if view is not None and opts.silhouette_weight > 0:
        _, viol, tested = _silhouette_targets(model, sim, view, opts.free_space_tolerance_m)
        score += opts.silhouette_weight * tau ** 2 * len(viol) / max(tested, 1)
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


def _halving(model: _Model, obs: np.ndarray, sims: list[_Similarity],
             viewpoint: np.ndarray | None, view: ViewConstraint | None, opts: IcpOptions,
             keep_last: int) -> list[_Similarity]:
    """Successive halving over start poses: every start gets a short ICP on few points,
    the best quarter goes on with more points and a tighter gate, and so on; returns the
    best ``keep_last`` (best first)."""
    coarse = replace(opts, estimate_scale=False, trim_fraction=max(opts.trim_fraction, 0.2),
                     rotation_prior_weight=0.0, edge_weight=0.0)
    levels = opts.max_correspondence_m[:2] or (0.02,)
    rounds = [(150, levels[0], 6), (300, levels[-1], 8), (600, levels[-1], 8)]
    for round_i, (n_points, level_m, iters) in enumerate(rounds):
        sub = _subsample(obs, n_points, opts.seed + round_i)
        sims = [_icp(model, sub, s, viewpoint, None, coarse, (level_m,), iters) for s in sims]
        scores = [_evaluate(model, sub, s, viewpoint, view, opts)[2] for s in sims]
        order = np.argsort(scores, kind="stable")
        last = round_i == len(rounds) - 1
        keep = keep_last if last else max(keep_last, len(sims) // 4)
        sims = [sims[i] for i in order[:max(keep, 1)]]
    return sims


def _global_starts(model: _Model, mesh: trimesh.Trimesh, obs: np.ndarray,
                   viewpoint: np.ndarray | None, up: np.ndarray, opts: IcpOptions
                   ) -> list[_Similarity]:
    """Start poses of the global search: each model axis (frame and oriented-box axes,
    both signs) along ``up`` at ``global_yaw_steps`` yaws, the model centre half a radius
    behind the observed centroid."""
    axes = [np.eye(3)]
    try:
        axes.append(np.asarray(mesh.bounding_box_oriented.primitive.transform)[:3, :3].T)
    except Exception:  # degenerate meshes have no oriented box; the frame axes suffice
        pass
    rots = rotation_hypotheses(np.concatenate(axes), up, opts.global_yaw_steps)
    centroid = obs.mean(axis=0)
    ray = centroid - viewpoint if viewpoint is not None else -np.asarray(up, dtype=np.float64)
    ray = ray / np.linalg.norm(ray)
    centre_w = centroid + ray * 0.5 * model.radius
    sims = []
    for rot in rots:
        world_from_obj = np.eye(4)
        world_from_obj[:3, :3] = rot
        world_from_obj[:3, 3] = centre_w - rot @ model.center
        sims.append(_Similarity.from_pose(world_from_obj, 1.0))
    return sims


def _yaw_starts(world_from_prior: np.ndarray, obs: np.ndarray, up: np.ndarray,
                steps: int) -> list[_Similarity]:
    """The given pose turned about ``up`` (through the observed centroid) by every
    ``360 / steps`` degrees, the given pose first."""
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    pivot = obs.mean(axis=0)
    sims = []
    for k in range(steps):
        turn = np.eye(4)
        turn[:3, :3] = Rotation.from_rotvec(up * 2 * np.pi * k / steps).as_matrix()
        turn[:3, 3] = pivot - turn[:3, :3] @ pivot
        sims.append(_Similarity.from_pose(turn @ world_from_prior, 1.0))
    return sims


def register_prior(mesh: trimesh.Trimesh, observed_points: np.ndarray,
                   world_from_prior: np.ndarray | None = None,
                   viewpoint: np.ndarray | None = None,
                   view: ViewConstraint | None = None,
                   up: np.ndarray | None = None,
                   options: IcpOptions = IcpOptions()) -> RegistrationResult:
    """Register a complete prior mesh to the observed points of its instance.

    With ``world_from_prior``: ICP from it, and from the same pose turned about ``up`` by
    multiples of ``360 / local_yaw_steps`` degrees (single-image pose estimates often get
    the yaw wrong); a turned start replaces the given one only when it scores clearly
    better (``local_switch_ratio``). When the result still explains fewer than
    ``global_fallback_fitness`` of the points, or without an initial pose, a global search
    over rotation hypotheses runs too.

    Parameters
    ----------
    mesh : the prior, in its own frame, metres.
    observed_points : (N, 3) world points of the instance (one partial view).
    world_from_prior : (4, 4) initial pose, or None for a global search.
    viewpoint : (3,) camera centre, world frame; enables visibility-aware matching
        (defaults to the camera of ``view``).
    view : the instance's :class:`ViewConstraint` (free-space term), or None.
    up : (3,) world up (the support normal) for the hypotheses; default +z.
    options : :class:`IcpOptions`.

    Returns
    -------
    :class:`RegistrationResult`; ``ValueError`` with fewer than 10 observed points.
    """
    obs_all = np.asarray(observed_points, dtype=np.float64).reshape(-1, 3)
    obs_all = obs_all[np.all(np.isfinite(obs_all), axis=1)]
    if len(obs_all) < 10:
        raise ValueError("registration needs at least 10 observed points")
    if viewpoint is None and view is not None:
        viewpoint = view.world_from_camera[:3, 3]
    obs = _subsample(obs_all, options.max_observed_points, options.seed)
    model = _sample_model(mesh, options.model_samples, options.seed, options.silhouette_samples)
    vp = None if viewpoint is None else np.asarray(viewpoint, dtype=np.float64)
    up_vec = np.asarray(up if up is not None else (0.0, 0.0, 1.0), dtype=np.float64)
    sched, iters = options.max_correspondence_m, options.iterations_per_level

    def refine(start: _Similarity) -> tuple[tuple[float, float, float], _Similarity]:
        sim = _icp(model, obs, start, vp, view, options, sched, iters)
        return _evaluate(model, obs, sim, vp, view, options), sim

    best = None
    if world_from_prior is not None:
        best = refine(_Similarity.from_pose(world_from_prior, 1.0))
        if options.local_yaw_steps > 1:
            starts = _yaw_starts(world_from_prior, obs, up_vec, options.local_yaw_steps)
            for start in _halving(model, obs, starts, vp, view, options, 1):
                cand = refine(start)
                # symmetric shapes fit equally well turned: keep the given pose unless a
                # turned one is clearly better (by a ratio and by a 1/5-inlier margin)
                margin = (0.2 * options.inlier_m) ** 2
                if cand[0][2] < options.local_switch_ratio * best[0][2] - margin:
                    best = cand
    if best is None or best[0][0] < options.global_fallback_fitness:
        starts = _global_starts(model, mesh, obs, vp, up_vec, options)
        for start in _halving(model, obs, starts, vp, view, options, options.global_keep):
            cand = refine(start)
            if best is None or cand[0][2] < best[0][2]:
                best = cand
    assert best is not None
    sim = best[1]
    final_obs = _subsample(obs_all, 20000, options.seed)
    fitness, rmse, _ = _evaluate(model, final_obs, sim, vp, None, options)
    world_from_object, scale = sim.result()
    return RegistrationResult(world_from_object=world_from_object, scale=scale,
                              fitness=fitness, rmse_m=rmse)


def voxel_downsample(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """(M, 3) centroid of the points in each occupied voxel of size ``voxel_m``.

    Evens out the density of a depth image's points (near surfaces have more pixels).
    ``voxel_m <= 0`` returns the points unchanged.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if voxel_m <= 0 or len(pts) == 0:
        return pts
    keys = np.floor(pts / voxel_m).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    sums = np.zeros((len(counts), 3))
    np.add.at(sums, inverse, pts)
    return sums / counts[:, None]


def surface_fit(mesh_world: trimesh.Trimesh, points: np.ndarray, inlier_m: float = 0.005,
                samples: int = 20000, seed: int = 0) -> tuple[float, float]:
    """(fitness, rmse_m) of observed points against a posed mesh surface.

    fitness : fraction of (N, 3) ``points`` within ``inlier_m`` of the surface.
    rmse_m : RMS distance of those inliers (inf when there is none).
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    model = _sample_model(mesh_world, samples, seed, 1)
    dist, idx = model.tree.query(pts)
    plane = np.abs(np.einsum("nj,nj->n", pts - model.points[idx], model.normals[idx]))
    d = np.where(dist < 3 * inlier_m, plane, dist)
    inl = d < inlier_m
    fitness = float(inl.mean()) if len(d) else 0.0
    rmse = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else float("inf")
    return fitness, rmse
