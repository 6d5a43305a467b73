"""Per-axis scale of a registered prior, and its bottom on the support plane.

A single-image 3D model gets an object's proportions wrong by up to ~15 % *per axis*; an
isotropic scale (what :func:`r2s.geometry.registration.register_prior` estimates) leaves
most of that error, and a prior that ends up a few millimetres into the table or floating
above it is then pushed around by the later physics stages. Starting from a registered
pose, this refines rotation, translation and a bounded scale per prior axis together
(Gauss-Newton), with

- the observed points against the camera-facing model surface (point-to-plane, Tukey
  weights, trimmed; points past a face's edge keep their tangential residual);
- the free-space term (:mod:`r2s.geometry.free_space`): model points the camera sees past,
  outside the mask, pulled to the mask;
- a support term: when the model's lowest point is within ``contact_m`` of the support
  plane (the object rests on the table, not on another object), its lowest samples are
  pulled onto the plane;
- a ridge keeping each axis scale near its start (an axis the camera does not see is not
  constrained by the data).

Frames: the model's samples are in the prior frame scaled by the current per-axis scale
``s`` (3,) about the prior's bounding-box centre ``c``; world points are
``x = world_from_object @ (c + s * (p - c))`` for prior points ``p``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from r2s.geometry.free_space import ViewConstraint, free_space_violations


@dataclass(frozen=True)
class RefineOptions:
    """Settings of :func:`refine_axis_scale`.

    Attributes
    ----------
    schedule_m : correspondence gates (world metres), coarse to fine; Tukey width follows.
    iterations_per_level : Gauss-Newton iterations per gate.
    trim_fraction : largest point-to-plane residuals dropped each iteration.
    scale_bounds : bounds of the total per-axis scale (relative to the unscaled prior).
    scale_ridge : pull of each axis scale towards its start, relative to the data term's
        weight times the model radius squared.
    edge_weight : weight of the tangential residual of points past a face's edge.
    silhouette_weight : weight of the free-space term (1 = like the data term when every
        tested model point violates).
    free_space_tolerance_m : see :func:`free_space_violations`.
    support_weight : weight of the support term (1 = like the data term).
    contact_m : the support term applies when the model's lowest point is within this of
        the plane (either side).
    bottom_band_m : model samples within this of the lowest one form the bottom.
    samples : model surface samples.
    seed : sampling seed.
    """

    schedule_m: tuple[float, ...] = (0.01, 0.005)
    iterations_per_level: int = 10
    trim_fraction: float = 0.1
    scale_bounds: tuple[float, float] = (0.8, 1.25)
    scale_ridge: float = 0.05
    edge_weight: float = 1.0
    silhouette_weight: float = 1.0
    free_space_tolerance_m: float = 0.01
    support_weight: float = 1.0
    contact_m: float = 0.015
    bottom_band_m: float = 0.002
    support_one_sided: bool = True
    samples: int = 12000
    seed: int = 0


@dataclass(frozen=True)
class RefinedPose:
    """world_from_object (4, 4) rigid, acting on prior points scaled per axis about
    ``centre`` (prior frame, (3,)) by ``axis_scale`` (3,); ``on_support`` says whether
    the support term was active at the end."""

    world_from_object: np.ndarray
    axis_scale: np.ndarray
    centre: np.ndarray
    on_support: bool

    def object_mesh(self, prior: trimesh.Trimesh) -> tuple[trimesh.Trimesh, np.ndarray]:
        """The prior recentred on ``centre`` and scaled per axis (object frame), and the
        (4, 4) world_from_object of that mesh."""
        mesh = prior.copy()
        mesh.apply_translation(-self.centre)
        mesh.apply_transform(np.diag([*self.axis_scale, 1.0]))
        pose = self.world_from_object.copy()
        pose[:3, 3] += pose[:3, :3] @ (self.axis_scale * self.centre)
        return mesh, pose


def _rows_3d(q: np.ndarray, local: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """(V, 3, 9) Jacobian of world model points w.r.t. (rotation about the pivot, translation,
    log axis scale): ``q`` (V, 3) point - pivot (world), ``local`` (V, 3) scaled prior-frame
    offsets from the centre, ``rot`` the object's rotation."""
    J = np.zeros((len(q), 3, 9))
    # d(w x q)/dw = -[q]x
    J[:, 0, 1], J[:, 0, 2] = q[:, 2], -q[:, 1]
    J[:, 1, 0], J[:, 1, 2] = -q[:, 2], q[:, 0]
    J[:, 2, 0], J[:, 2, 1] = q[:, 1], -q[:, 0]
    J[:, :, 3:6] = np.eye(3)
    J[:, :, 6:9] = rot[None, :, :] * local[:, None, :]
    return J


def refine_axis_scale(mesh: trimesh.Trimesh, observed_points: np.ndarray,
                      world_from_object: np.ndarray, scale: float,
                      viewpoint: np.ndarray, view: ViewConstraint | None = None,
                      support: tuple[np.ndarray, np.ndarray] | None = None,
                      options: RefineOptions = RefineOptions()) -> RefinedPose:
    """Refine a registered prior's pose together with a scale per prior axis.

    Parameters
    ----------
    mesh : the prior, its own frame, metres (unscaled).
    observed_points : (N, 3) world points of the instance.
    world_from_object, scale : the registration's pose and isotropic scale (the pose maps
        ``scale * p`` to the world).
    viewpoint : (3,) camera centre, world.
    view : the instance's free-space constraint, or None.
    support : (point (3,), unit normal (3,)) of the support plane, or None.
    """
    o = options
    obs = np.asarray(observed_points, dtype=np.float64).reshape(-1, 3)
    pts, nrm = _surface_samples(mesh, o.samples, o.seed)
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    centre = 0.5 * (verts.min(axis=0) + verts.max(axis=0))
    off0 = pts - centre
    radius = float(0.5 * np.linalg.norm(pts.max(axis=0) - pts.min(axis=0))) * scale
    spacing = float(np.sqrt(max(mesh.area, 1e-12) / max(len(pts), 1))) * scale
    # pose acting on the centred, scaled prior: x = R (s * off) + t
    R = np.asarray(world_from_object, dtype=np.float64)[:3, :3].copy()
    t = np.asarray(world_from_object, dtype=np.float64)[:3, 3] + R @ (scale * centre)
    s = np.full(3, float(scale))
    s_start = s.copy()
    lo, hi = np.log(o.scale_bounds[0]), np.log(o.scale_bounds[1])
    on_support = False
    rng = np.random.default_rng(o.seed)
    fs_idx = rng.choice(len(pts), size=min(3000, len(pts)), replace=False)
    for gate in o.schedule_m:
        for _ in range(o.iterations_per_level):
            local = s * off0
            xw = local @ R.T + t
            n_obj = nrm / s
            n_obj /= np.linalg.norm(n_obj, axis=1, keepdims=True)
            nw = n_obj @ R.T
            matched = _camera_facing_matches(xw, nw, obs, np.asarray(viewpoint, np.float64),
                                             gate, o.trim_fraction)
            if matched is None:
                break
            idx, y, r = matched
            w = np.clip(1.0 - (r / gate) ** 2, 0.0, None) ** 2
            pivot = t
            J3 = _rows_3d(xw[idx] - pivot, local[idx], R)
            # point-to-plane: r = n . (y - x)  ->  dr = -n . dx
            J = -np.einsum("vk,vkj->vj", nw[idx], J3)
            A = J.T @ (J * w[:, None])
            b = -J.T @ (w * r)
            wsum = float(w.sum())
            if o.edge_weight > 0 and gate == o.schedule_m[-1]:
                _add_edge_terms(A, b, y - xw[idx], nw[idx], J3, w, spacing, o.edge_weight)
            if view is not None and o.silhouette_weight > 0:
                _add_free_space_terms(A, b, view, xw, nw, local, R, pivot, fs_idx, wsum,
                                      gate, o)
            on_support = False
            if support is not None and o.support_weight > 0:
                on_support = _add_support_terms(A, b, support, xw, local, R, pivot, wsum, o)
            lam = o.scale_ridge * wsum * radius ** 2
            A[6:, 6:] += lam * np.eye(3)
            b[6:] -= lam * np.log(s / s_start)
            A += np.eye(9) * 1e-9 * max(np.trace(A) / 9, 1e-12)
            delta = _solve_or_none(A, b)
            if delta is None:
                break
            # x' = R_inc (x - pivot) + pivot + dt, scale s' = s * exp(ds)
            R_inc = Rotation.from_rotvec(delta[:3]).as_matrix()
            R = R_inc @ R
            t = t + delta[3:6]
            s = np.exp(np.clip(np.log(s) + delta[6:], lo, hi))
            if np.linalg.norm(delta[:3]) < 1e-6 and np.linalg.norm(delta[3:]) < 1e-7:
                break
    out = np.block([[R, (t - R @ (s * centre))[:, None]], [np.zeros((1, 3)), np.ones((1, 1))]])
    return RefinedPose(world_from_object=out, axis_scale=s, centre=centre, on_support=on_support)


def _add_edge_terms(A: np.ndarray, b: np.ndarray, r3: np.ndarray, nw: np.ndarray,
                    J3: np.ndarray, w: np.ndarray, spacing: float, weight: float) -> None:
    """Add to the normal equations (A (9, 9), b (9,)) the tangential pull of matches that
    lie off the prior's edge by more than 1.5 sample spacings. r3, nw: (n, 3) residual
    vectors and world normals of the matches; J3 (n, 3, 9) their point Jacobians."""
    tang = r3 - np.einsum("nj,nj->n", r3, nw)[:, None] * nw
    off = np.linalg.norm(tang, axis=1) > 1.5 * spacing
    if off.any():
        Jt = -J3[off]
        we = weight * w[off]
        A += np.einsum("vki,vkj,v->ij", Jt, Jt, we)
        b -= np.einsum("vki,vk,v->i", Jt, tang[off], we)


def _add_free_space_terms(A: np.ndarray, b: np.ndarray, view: "ViewConstraint",
                          xw: np.ndarray, nw: np.ndarray, local: np.ndarray, R: np.ndarray,
                          pivot: np.ndarray, fs_idx: np.ndarray, wsum: float, gate: float,
                          o: "RefineOptions") -> None:
    """Add the pull of samples lying in space the camera saw empty towards their targets
    (r2s.geometry.free_space); xw, nw, local (n, 3): world points, world normals, scaled
    object-frame offsets; fs_idx: the samples tested."""
    viol, targets, tested = free_space_violations(view, xw[fs_idx], nw[fs_idx],
                                                  o.free_space_tolerance_m)
    if not viol.any():
        return
    vi = fs_idx[viol]
    r3 = targets - xw[vi]
    rn = np.linalg.norm(r3, axis=1)
    ws = o.silhouette_weight * wsum / max(tested, 1)
    ws = ws * np.minimum(1.0, gate / np.maximum(rn, 1e-12))
    Jf = -_rows_3d(xw[vi] - pivot, local[vi], R)
    A += np.einsum("vki,vkj,v->ij", Jf, Jf, ws)
    b -= np.einsum("vki,vk,v->i", Jf, r3, ws)


def _add_support_terms(A: np.ndarray, b: np.ndarray, support: tuple, xw: np.ndarray,
                       local: np.ndarray, R: np.ndarray, pivot: np.ndarray, wsum: float,
                       o: "RefineOptions") -> bool:
    """Add the support plane's push (one-sided: samples below it) or pull (the bottom band
    onto it); returns whether the prior touches the plane (lowest sample < contact_m)."""
    p0, n0 = np.asarray(support[0], float), np.asarray(support[1], float)
    h = (xw - p0) @ n0
    if not h.min() < o.contact_m:
        return False
    bottom = (np.flatnonzero(h < 0.0) if o.support_one_sided
              else np.flatnonzero(h < h.min() + o.bottom_band_m))
    if len(bottom):
        Jb = np.einsum("k,vkj->vj", n0, _rows_3d(xw[bottom] - pivot, local[bottom], R))
        wb = o.support_weight * wsum / max(len(bottom), 50)
        A += wb * (Jb.T @ Jb)
        b -= wb * (Jb.T @ h[bottom])
    return True


def _camera_facing_matches(xw: np.ndarray, nw: np.ndarray, obs: np.ndarray, vp: np.ndarray,
                           gate: float, trim_fraction: float):
    """Match each observed point (obs (N, 3)) to the nearest camera-facing prior sample
    (xw, nw (n, 3), world) within ``gate`` m, drop the worst ``trim_fraction`` by |r|.
    Returns (sample index (m,), observed point (m, 3), point-to-plane residual (m,)) or
    None when too few samples face the camera (< 10) or match (< 20)."""
    facing = np.flatnonzero(np.einsum("nj,nj->n", nw, vp - xw) > 0)
    if len(facing) < 10:
        return None
    _, pos = cKDTree(xw[facing]).query(obs, k=1, distance_upper_bound=gate)
    found = pos < len(facing)
    if found.sum() < 20:
        return None
    idx = facing[pos[found]]
    y = obs[found]
    r = np.einsum("nj,nj->n", y - xw[idx], nw[idx])
    if trim_fraction > 0:
        cut = np.quantile(np.abs(r), 1.0 - trim_fraction)
        sel = np.abs(r) <= max(cut, 1e-9)
        idx, y, r = idx[sel], y[sel], r[sel]
    return idx, y, r


def _surface_samples(mesh: trimesh.Trimesh, count: int, seed: int
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) surface points and (n, 3) unit face normals of ``mesh`` (its frame); samples
    on degenerate faces (no finite unit normal) are dropped."""
    pts, face_idx = trimesh.sample.sample_surface(mesh, count, seed=seed)
    nrm = np.asarray(mesh.face_normals)[face_idx]
    keep = np.all(np.isfinite(nrm), axis=1) & (np.linalg.norm(nrm, axis=1) > 0.5)
    return np.asarray(pts)[keep], nrm[keep]


def _solve_or_none(A: np.ndarray, b: np.ndarray):
    """The Gauss-Newton step A x = b, or None for a singular system."""
    try:
        return np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        return None
