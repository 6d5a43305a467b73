"""How big is the observed object compared with its prior? A free-scale ICP in the camera frame.

The observed points are scaled about their centroid (the fitted scale is the same as
about the camera centre, which is what a depth scale does, but decoupled from the
translation) while a rigid pose is refitted. Two terms:

- data: each observed point's distance to the model surface (exact closest points,
  Open3D), linearised along the direction to the closest point. A point-to-plane error
  cannot see the size of a box seen on three faces; the distance to the surface sees the
  faces' extents too. Observed -> model only, so occluded parts cost nothing, and Huber
  weights under a shrinking correspondence distance.
- silhouette: the data term is one-sided (an observation smaller than the model fits
  inside its faces), so the model's outer outline (mesh edges between front- and
  back-facing faces that lie on the border of the model's own ray-cast footprint) is
  pulled, from both sides, onto the instance's mask border, which lies half a pixel
  beyond the last mask pixel centre. Outline points next to a closer object (an
  occlusion border) are skipped.

``s`` is the scale of the prior that matches the observation: 1 for a metric prior and an
unbiased sensor, the depth scale for a biased one.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
import open3d as o3d
import trimesh
from scipy import ndimage
from scipy.spatial.transform import Rotation


@dataclass(frozen=True)
class ScaleFit:
    """Result of :func:`fit_prior_scale`.

    scale : prior scale that fits the observation; object_from_camera : (4, 4) similarity
    taking camera points to the model (scale included); fitness : fraction of points within ``inlier_m``; rmse_m : RMS
    distance of those; n_points : points used.
    """

    scale: float
    object_from_camera: np.ndarray
    fitness: float
    rmse_m: float
    n_points: int
    log_scale_axes: tuple = (0.0, 0.0, 0.0)
    """Log scale of the prior per camera axis (x, y across the view, z along the optical
    axis); all three are ``log(scale)`` unless the fit's ``axes`` freed them."""


EDGE_ALLOWANCE_PX = 0.5
"""How far (pixels) beyond the centre of the nearest mask pixel the silhouette may lie."""

MAX_STEP = 0.05
"""Largest step per iteration: radians, log scale, half correspondence distances."""

LOG_SCALE_BOUNDS = (float(np.log(0.7)), float(np.log(1.4)))
INLIER_M = 0.003
"""A point fits when it lies within this distance (m, the observation's units) of the model."""


@dataclass(frozen=True)
class FreeSpace:
    """What the camera saw around one instance: its silhouette.

    K : (3, 3); depth_m : (H, W) observed depth, NaN = none; own : (H, W) bool, the
    instance's mask; sdt : (H, W) signed distance (pixels) to the silhouette, which lies
    half a pixel beyond the last mask pixel centre (positive outside);
    grad : (2, H, W) d sdt / d (row, col); outside_nearest / inside_nearest : (2, H, W)
    (row, col) of the nearest mask / non-mask pixel; tolerance_m : depth margin that
    tells an occluder (closer) from background or the table.
    """

    K: np.ndarray
    depth_m: np.ndarray
    own: np.ndarray
    sdt: np.ndarray
    grad: np.ndarray
    outside_nearest: np.ndarray
    inside_nearest: np.ndarray
    tolerance_m: float = 0.01


def free_space(K: np.ndarray, depth_m: np.ndarray, mask: np.ndarray,
               tolerance_m: float = 0.01) -> FreeSpace:
    """Precompute :class:`FreeSpace` for one instance's (H, W) bool ``mask``."""
    own = np.asarray(mask, dtype=bool)
    d_out, near_own = ndimage.distance_transform_edt(~own, return_indices=True)
    d_in, near_other = ndimage.distance_transform_edt(own, return_indices=True)
    sdt = np.where(own, -(d_in - 0.5), d_out - 0.5)
    grad = np.stack(np.gradient(sdt))
    return FreeSpace(np.asarray(K, dtype=np.float64), np.asarray(depth_m, dtype=np.float64),
                     own, sdt, grad, near_own.astype(np.int64), near_other.astype(np.int64),
                     tolerance_m)


def _bilinear(img: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    return ndimage.map_coordinates(img, [rows, cols], order=1, mode="nearest")


def _contour_points(model: "SurfaceModel", cam_from_obj: np.ndarray, step_m: float
                    ) -> np.ndarray:
    """(P, 3) object-frame points along the mesh edges between front- and back-facing
    faces as seen from the camera (the outline of the model in the image)."""
    obj_from_cam = np.linalg.inv(cam_from_obj)
    eye = obj_from_cam[:3, 3]
    fa, edges = model.adjacency, model.adjacency_edges
    if not len(fa):
        return np.zeros((0, 3))
    v = model.vertices
    mid = 0.5 * (v[edges[:, 0]] + v[edges[:, 1]])
    to_eye = eye - mid
    f0 = np.einsum("ij,ij->i", model.face_normals[fa[:, 0]], to_eye) > 0
    f1 = np.einsum("ij,ij->i", model.face_normals[fa[:, 1]], to_eye) > 0
    contour = edges[f0 != f1]
    if not len(contour):
        return np.zeros((0, 3))
    a, b = v[contour[:, 0]], v[contour[:, 1]]
    n = np.maximum(1, np.ceil(np.linalg.norm(b - a, axis=1) / step_m).astype(np.int64))
    which = np.repeat(np.arange(len(contour)), n)
    t = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + 0.5) / np.repeat(n, n)
    return a[which] + t[:, None] * (b - a)[which]


def _on_footprint_edge(model: "SurfaceModel", cam_from_obj: np.ndarray, K: np.ndarray,
                       uv: np.ndarray, image_hw: tuple[int, int], margin_px: int = 4,
                       tolerance_px: float = 1.0) -> np.ndarray:
    """(P,) bool: which image points ``uv`` (P, 2) lie on the border of the model's own
    footprint (ray cast in a window around them)."""
    h, w = image_hw
    c0 = int(max(np.floor(uv[:, 0].min()) - margin_px, 0))
    c1 = int(min(np.ceil(uv[:, 0].max()) + margin_px + 1, w))
    r0 = int(max(np.floor(uv[:, 1].min()) - margin_px, 0))
    r1 = int(min(np.ceil(uv[:, 1].max()) + margin_px + 1, h))
    if c1 <= c0 or r1 <= r0:
        return np.zeros(len(uv), dtype=bool)
    v, u = np.mgrid[r0:r1, c0:c1].astype(np.float64)
    dirs_cam = np.stack([u, v, np.ones_like(u)], axis=-1) @ np.linalg.inv(K).T
    obj_from_cam = np.linalg.inv(cam_from_obj)
    origin = obj_from_cam[:3, 3]
    dirs = dirs_cam @ obj_from_cam[:3, :3].T
    rays = np.concatenate([np.broadcast_to(origin, dirs.shape), dirs], axis=-1)
    hit = np.isfinite(model.scene.cast_rays(
        o3d.core.Tensor(rays.astype(np.float32)))["t_hit"].numpy())
    if not hit.any():
        return np.zeros(len(uv), dtype=bool)
    d_out = ndimage.distance_transform_edt(~hit)
    d_in = ndimage.distance_transform_edt(hit)
    sdt = np.where(hit, -(d_in - 0.5), d_out - 0.5)
    return np.abs(_bilinear(sdt, uv[:, 1] - r0, uv[:, 0] - c0)) <= tolerance_px


def _silhouette_pairs(model: "SurfaceModel", cam_from_obj: np.ndarray, view: FreeSpace,
                      max_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Outline points of the model and where the observed silhouette wants them.

    Two-sided: an outline point outside the silhouette is pulled in, one inside is pushed
    out, each along the silhouette's normal in the image at its own depth. Points at an
    occlusion boundary (a closer object next to them) say nothing and are skipped.

    Returns (V, 3) targets (camera frame) and (V, 3) outline points (object frame).
    """
    scale = float(np.cbrt(abs(np.linalg.det(cam_from_obj[:3, :3]))))
    m = _contour_points(model, cam_from_obj, model.contour_step_m / max(scale, 1e-9))
    if not len(m):
        return np.zeros((0, 3)), np.zeros((0, 3))
    x = m @ cam_from_obj[:3, :3].T + cam_from_obj[:3, 3]
    z = x[:, 2]
    ok = z > 1e-3
    m, x, z = m[ok], x[ok], z[ok]
    uv = (x @ view.K.T)[:, :2] / z[:, None]
    h, w = view.own.shape
    rows, cols = uv[:, 1], uv[:, 0]
    ok = (rows >= 0) & (rows <= h - 1) & (cols >= 0) & (cols <= w - 1)
    m, z, uv, rows, cols = m[ok], z[ok], uv[ok], rows[ok], cols[ok]
    if not len(m):
        return np.zeros((0, 3)), np.zeros((0, 3))
    # only the outer outline: an inner rim or a self-occluded edge lies inside the
    # model's own footprint and says nothing about where the silhouette is
    outer = _on_footprint_edge(model, cam_from_obj, view.K, uv, (h, w))
    m, z, uv, rows, cols = m[outer], z[outer], uv[outer], rows[outer], cols[outer]
    r = _bilinear(view.sdt, rows, cols)
    ok = np.abs(r) <= max_px
    rr, cc = np.rint(rows).astype(np.int64), np.rint(cols).astype(np.int64)
    # the pixel on the other side of the silhouette: the point's own pixel when it is
    # outside, the nearest non-mask pixel when it is inside
    outside = view.sdt[rr, cc] > 0
    orow = np.where(outside, rr, view.inside_nearest[0, rr, cc])
    ocol = np.where(outside, cc, view.inside_nearest[1, rr, cc])
    d = view.depth_m[orow, ocol]
    occluded = np.isfinite(d) & (d < z - view.tolerance_m)
    ok &= ~occluded
    if not ok.any():
        return np.zeros((0, 3)), np.zeros((0, 3))
    g = np.stack([_bilinear(view.grad[1], rows[ok], cols[ok]),
                  _bilinear(view.grad[0], rows[ok], cols[ok])], axis=1)   # (du, dv)
    g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-9)
    goal = uv[ok] - r[ok, None] * g
    pix = np.hstack([goal, np.ones((len(goal), 1))])
    target = (pix @ np.linalg.inv(view.K).T) * z[ok, None]
    return target, m[ok]


class SurfaceModel:
    """Closest-point queries on a mesh (object frame), for :func:`fit_prior_scale`."""

    def __init__(self, mesh: trimesh.Trimesh, contour_step_m: float = 0.001):
        mesh = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), process=False)
        mesh.merge_vertices(merge_tex=True, merge_norm=True)  # edges need shared vertices
        self.vertices = np.asarray(mesh.vertices, dtype=np.float64)
        self.face_normals = np.asarray(mesh.face_normals, dtype=np.float64)
        self.adjacency = np.asarray(mesh.face_adjacency, dtype=np.int64).reshape(-1, 2)
        self.adjacency_edges = np.asarray(mesh.face_adjacency_edges, dtype=np.int64).reshape(-1, 2)
        self.contour_step_m = contour_step_m
        self.scene = o3d.t.geometry.RaycastingScene()
        tm = o3d.t.geometry.TriangleMesh()
        tm.vertex.positions = o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32))
        tm.triangle.indices = o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.int32))
        self.scene.add_triangles(tm)

    def closest(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) closest surface points and (N, 3) normals of their triangles."""
        ans = self.scene.compute_closest_points(
            o3d.core.Tensor(np.asarray(points, dtype=np.float32)))
        return (ans["points"].numpy().astype(np.float64),
                ans["primitive_normals"].numpy().astype(np.float64))


def _subsample(points: np.ndarray, count: int, seed: int) -> np.ndarray:
    if len(points) <= count:
        return points
    idx = np.random.default_rng(seed).choice(len(points), size=count, replace=False)
    return points[np.sort(idx)]


def _cam_from_obj(rot: np.ndarray, trans: np.ndarray, centre: np.ndarray,
                  log_s: np.ndarray) -> np.ndarray:
    """(4, 4) map taking model points to the camera frame (inverse of the fit map);
    ``log_s``: the log scale, one value or one per camera axis (3,)."""
    log_s = np.broadcast_to(np.asarray(log_s, dtype=np.float64), (3,))
    out = np.eye(4)
    if np.all(log_s == log_s[0]):  # one scale: a similarity
        s = float(np.exp(log_s[0]))
        out[:3, :3] = s * rot.T
        out[:3, 3] = centre - s * rot.T @ trans
        return out
    s3 = np.exp(log_s)
    out[:3, :3] = s3[:, None] * rot.T
    out[:3, 3] = centre - s3 * (rot.T @ trans)
    return out


def _with_free_space(model: "SurfaceModel", view: FreeSpace, rot: np.ndarray,
                     trans: np.ndarray, centre: np.ndarray, log_s: np.ndarray, pairs: tuple,
                     weight: float, max_px: float) -> tuple:
    """Append the silhouette pairs to the (y, q, u, e, w) correspondence arrays."""
    target_cam, m = _silhouette_pairs(model, _cam_from_obj(rot, trans, centre, log_s), view,
                                      max_px)
    if not len(m):
        return pairs
    q = (target_cam - centre) * np.exp(-log_s)
    y = q @ rot.T + trans
    d = y - m
    dist = np.linalg.norm(d, axis=1)
    keep = dist > 1e-9
    y, q, d, dist = y[keep], q[keep], d[keep], dist[keep]
    u = d / dist[:, None]
    yo, qo, uo, eo, wo = pairs
    return (np.vstack([yo, y]), np.vstack([qo, q]), np.vstack([uo, u]),
            np.concatenate([eo, dist]), np.concatenate([wo, np.full(len(dist), weight)]))


SCALE_AXES = {"isotropic": ((0, 1, 2),), "across_along": ((0, 1), (2,))}
"""How the camera axes share scale parameters: one scale for all three, or one across
the view (x, y) and one along the optical axis (z)."""


@dataclass
class _Pose:
    """The fit's state: model point = rot diag(exp(-log_s)) (camera point - centre) + trans."""

    rot: np.ndarray
    trans: np.ndarray
    log_s: np.ndarray


def _gauss_newton_step(model: SurfaceModel, p: np.ndarray, p_cam: np.ndarray,
                       centre: np.ndarray, pose: _Pose, max_d: float, groups: tuple,
                       fit_rotation: bool, view: FreeSpace | None,
                       free_space_weight: float,
                       log_scale_bounds: tuple[float, float] = LOG_SCALE_BOUNDS
                       ) -> Optional[np.ndarray]:
    """One damped, Huber-weighted Gauss-Newton step of the free-scale ICP (updates
    ``pose`` in place); returns the step (rotation, translation, scales; the rotation part
    zero when held), None when too few correspondences are left."""
    n_par = (6 if fit_rotation else 3) + len(groups)
    q = p * np.exp(-pose.log_s)
    y = q @ pose.rot.T + pose.trans
    c, nf = model.closest(y)
    d = y - c
    dist = np.linalg.norm(d, axis=1)
    ok = dist < max_d
    if ok.sum() < max(10, n_par + 1):
        return None
    u = np.where(dist[:, None] > 1e-6, d / np.maximum(dist, 1e-12)[:, None], nf)[ok]
    yo, qo = y[ok], q[ok]
    e = np.einsum("ij,ij->i", u, d[ok])
    delta = max_d / 3.0
    w = np.where(np.abs(e) <= delta, 1.0, delta / np.maximum(np.abs(e), 1e-12))
    if view is not None:
        max_px = max_d * view.K[0, 0] / max(float(np.median(p_cam[:, 2])), 1e-3)
        yo, qo, u, e, w = _with_free_space(model, view, pose.rot, pose.trans, centre,
                                           pose.log_s, (yo, qo, u, e, w), free_space_weight,
                                           max_px)
    cols = ([np.cross(yo, u)] if fit_rotation else []) + [u]
    if groups:
        if len(groups) == 1:
            cols.append(-np.einsum("ij,ij->i", u, qo @ pose.rot.T)[:, None])
        else:
            d_axis = -(u @ pose.rot) * qo  # d e / d log_s per camera axis
            cols += [d_axis[:, list(g)].sum(axis=1)[:, None] for g in groups]
    J = np.hstack(cols)
    A = J.T @ (J * w[:, None])
    A += 1e-3 * np.diag(np.diag(A)) + 1e-12 * np.eye(n_par)  # Levenberg damping
    x = -np.linalg.solve(A, J.T @ (w * e))
    if not fit_rotation:
        x = np.concatenate([np.zeros(3), x])
    x *= min(1.0, MAX_STEP / max(np.abs(x[:3]).max(), 0.1 * np.abs(x[3:6]).max() / max_d,
                                 np.abs(x[6:]).max() if groups else 0.0, 1e-12))
    dR = Rotation.from_rotvec(x[:3]).as_matrix()
    pose.rot = dR @ pose.rot
    pose.trans = dR @ pose.trans + x[3:6]
    for g, step in zip(groups, x[6:]):
        pose.log_s[list(g)] = np.clip(pose.log_s[list(g)] + step, *log_scale_bounds)
    return x


def fit_prior_scale(model: SurfaceModel, points_camera: np.ndarray,
                    object_from_camera: np.ndarray,
                    schedule_m: tuple[float, ...] = (0.02, 0.01, 0.005, 0.003),
                    iterations_per_level: int = 10, inlier_m: float = INLIER_M,
                    max_points: int = 1500, fit_scale: bool = True, seed: int = 0,
                    view: FreeSpace | None = None, free_space_weight: float = 1.0,
                    axes: str = "isotropic", fit_rotation: bool = True,
                    log_scale_bounds: tuple[float, float] = LOG_SCALE_BOUNDS) -> ScaleFit:
    """Fit pose and scale of a model to observed points.

    Parameters
    ----------
    model : the prior's surface, object frame (metric).
    points_camera : (N, 3) observed points, camera frame (the camera centre is the origin).
    object_from_camera : (4, 4) initial pose: a rotation, or a rotation times one scale
        (the fit then starts from that scale).
    schedule_m : correspondence distances, coarse to fine.
    fit_scale : False holds the scale at its start (a rigid fit).
    view : the instance's :class:`FreeSpace` (the silhouette term), or None.
    free_space_weight : weight of a silhouette pair relative to an observed point.
    axes : a key of :data:`SCALE_AXES`; "across_along" fits one scale across the view and
        one along the optical axis (``ScaleFit.log_scale_axes``), about the points' centroid.
    fit_rotation : False holds the rotation at its start (translation and scale free).
    log_scale_bounds : the range the fitted log scale is kept in (default 0.7-1.4).

    Returns
    -------
    :class:`ScaleFit`.
    """
    p_cam = _subsample(np.asarray(points_camera, dtype=np.float64), max_points, seed)
    # scale about the points' centroid (not the camera centre) so that scale and
    # translation are nearly independent; the fitted scale is the same
    centre = p_cam.mean(axis=0)
    p = p_cam - centre
    start = np.asarray(object_from_camera, dtype=np.float64)
    start_log_s = -float(np.log(np.cbrt(abs(np.linalg.det(start[:3, :3])))))
    start_log_s = 0.0 if abs(start_log_s) < 1e-9 else start_log_s  # a rotation
    rot = start[:3, :3] * np.exp(start_log_s)
    pose = _Pose(rot.copy(), start[:3, 3] + start[:3, :3] @ centre, np.full(3, start_log_s))
    for level, max_d in enumerate(schedule_m):
        # the coarse levels align rigidly; the scale is freed once the pose is close
        with_scale = fit_scale and level >= len(schedule_m) // 2
        for _ in range(iterations_per_level):
            x = _gauss_newton_step(model, p, p_cam, centre, pose, max_d,
                                   SCALE_AXES[axes] if with_scale else (), fit_rotation,
                                   view, free_space_weight, log_scale_bounds)
            if x is None or np.abs(x).max() < 1e-7:
                break
    return _scale_fit(model, p, centre, pose, inlier_m)


def _scale_fit(model: SurfaceModel, p: np.ndarray, centre: np.ndarray, pose: _Pose,
               inlier_m: float) -> ScaleFit:
    """The :class:`ScaleFit` of a converged pose (fitness and RMSE in observation units)."""
    log_s = pose.log_s
    q = p * np.exp(-log_s)
    y = q @ pose.rot.T + pose.trans
    c, _ = model.closest(y)
    mean_log_s = float(log_s[0] if np.all(log_s == log_s[0]) else np.mean(log_s))
    dist = np.linalg.norm(y - c, axis=1) * np.exp(mean_log_s)  # back to observation units
    inl = dist < inlier_m
    out = np.eye(4)
    # y = R diag(exp(-log_s)) (p_cam - centre) + trans, as one (4, 4) map
    out[:3, :3] = pose.rot * np.exp(-log_s)
    out[:3, 3] = pose.trans - pose.rot @ (centre * np.exp(-log_s))
    return ScaleFit(scale=float(np.exp(mean_log_s)), object_from_camera=out,
                    fitness=float(inl.mean()) if len(inl) else 0.0,
                    rmse_m=float(np.sqrt(np.mean(dist[inl] ** 2))) if inl.any() else float("nan"),
                    n_points=int(len(p)), log_scale_axes=tuple(float(v) for v in log_s))
