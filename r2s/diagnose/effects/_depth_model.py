"""The sensor's depth bias ``z_observed = s * z_true + o`` and what it does to the data.

A pixel's back-projected point is ``z * K^-1 [u, v, 1]``, so a biased depth moves every
point along its ray by the factor ``z_obs / z_true = s + o / z_true``. An object of known
(metric) size therefore appears scaled by that factor: registering its prior to the
observation needs the prior scaled by ``s + o s / (z_obs - o)`` (``z_obs``: the object's
observed depth). A pure scale scales the whole scene about the camera centre (planes stay
planes with the same normal, so the table says nothing about ``s``); an offset makes the
apparent size depend on depth, and bends an obliquely seen table
(:mod:`r2s.diagnose.stats.table_offset`). From the priors of one view with objects at
similar depths, ``s`` and ``o`` are nearly collinear; the BIC then prefers the
one-parameter versions.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Optional

import numpy as np
from scipy.optimize import least_squares

from r2s.diagnose.data import RegistrationData, ScaleObs, SupportData
from r2s.diagnose.stats.table_height import TableHeightEvidence
from r2s.diagnose.stats.table_offset import TableOffsetEvidence
from r2s.geometry.plane import least_squares_plane


def apparent_scale(depth_obs_m: np.ndarray, scale: float, offset_m: float) -> np.ndarray:
    """(n,) size factor of an object observed at ``depth_obs_m`` under bias (s, o)."""
    z = np.asarray(depth_obs_m, dtype=np.float64)
    return scale + offset_m * scale / np.maximum(z - offset_m, 1e-6)


def correct_depth(depth_m: np.ndarray, scale: float, offset_m: float) -> np.ndarray:
    """True depth from observed depth: ``(z - o) / s`` (NaN stays NaN)."""
    return ((np.asarray(depth_m, dtype=np.float64) - offset_m) / scale).astype(np.asarray(depth_m).dtype)


def fit_bias(data: Optional[RegistrationData], fit_scale: bool, fit_offset: bool,
             table: Optional[TableOffsetEvidence] = None,
             height: Optional[TableHeightEvidence] = None) -> tuple[float, float]:
    """Robust (Huber) least-squares (s, o) from per-object prior scales (log residuals),
    for ``o`` the table's shape (``table``: one more residual, ``(o - o_T) / sigma_T``) and
    the table's height where the declared world gives it (``height``: one more residual,
    the height left after the correction over its noise level).

    With only one of the two free, the other is held at its neutral value (1 or 0).
    """
    used = data.used() if data is not None else ()
    log_s = np.log([o.scale for o in used]) if used else np.zeros(0)
    z = np.array([o.depth_m for o in used], dtype=np.float64)
    sigma = data.scale_sigma if data is not None else 1.0
    use_table = table is not None and fit_offset

    def unpack(x: np.ndarray) -> tuple[float, float]:
        k = 0
        s = 1.0
        o = 0.0
        if fit_scale:
            s = float(np.exp(x[k]))
            k += 1
        if fit_offset:
            o = float(x[k])
        return s, o

    def fun(x: np.ndarray) -> np.ndarray:
        s, o = unpack(x)
        r = (log_s - np.log(apparent_scale(z, s, o))) / sigma
        if use_table:
            r = np.append(r, (o - table.offset_m) / table.sigma_m)
        if height is not None:
            r = np.append(r, height.residual_m(s, o) / height.sigma_m)
        return r

    x0 = []
    if fit_scale:
        if height is not None and not fit_offset:
            x0.append(float(np.log(height.distance_m / height.model_distance_m)))
        else:
            x0.append(float(np.mean(log_s)) if len(log_s) else 0.0)
    if fit_offset:
        if use_table:
            x0.append(float(table.offset_m))
        elif height is not None and not fit_scale:
            x0.append(float((1.0 - height.model_distance_m / height.distance_m)
                            / height.mean_inverse_depth))
        else:
            x0.append(0.0 if fit_scale or not len(log_s)
                      else float(np.mean((np.exp(log_s) - 1.0) * z)))
    # Huber: one prior that is far off in size (a bad prior, a bad fit) must not drag s
    sol = least_squares(fun, np.array(x0), loss="huber", f_scale=1.5)
    return unpack(sol.x)


def offset_sigma_from_priors(data: Optional[RegistrationData], fit_scale: bool,
                             offset_m: float) -> float:
    """Standard error (m) of the offset fitted to the prior scales alone (linearised WLS;
    with ``fit_scale`` the scale is free too). Infinite when they cannot tell it."""
    used = data.used() if data is not None else ()
    n_par = 2 if fit_scale else 1
    if len(used) < n_par:
        return float("inf")
    z = np.array([o.depth_m for o in used], dtype=np.float64)
    cols = [np.ones_like(z)] if fit_scale else []
    cols.append(1.0 / np.maximum(z - offset_m, 1e-6))   # d log(apparent scale) / d o
    J = np.stack(cols, axis=1) / data.scale_sigma
    info = J.T @ J
    if abs(np.linalg.det(info)) < 1e-12:
        return float("inf")
    return float(np.sqrt(np.linalg.inv(info)[-1, -1]))


def offset_information_from_priors(data: Optional[RegistrationData]) -> float:
    """Fisher information (1/m^2) of the prior scales about an offset alone."""
    used = data.used() if data is not None else ()
    if not used:
        return 0.0
    z = np.array([o.depth_m for o in used], dtype=np.float64)
    return float(np.sum(1.0 / z ** 2) / data.scale_sigma ** 2)


def corrected_registration(data: RegistrationData, scale: float,
                           offset_m: float) -> RegistrationData:
    """The registration residual predicted after correcting the depth by (s, o)."""
    objs = []
    for o in data.objects:
        factor = float(apparent_scale(np.array([o.depth_m]), scale, offset_m)[0])
        objs.append(replace(o, scale=o.scale / factor, depth_m=(o.depth_m - offset_m) / scale))
    return replace(data, objects=tuple(objs))


def scale_obs(id: int, scale: float, depth_m: float) -> ScaleObs:  # noqa: A002
    """Shorthand for tests and hand-made residuals."""
    return ScaleObs(id=id, scale=scale, depth_m=depth_m)


def corrected_support(support: SupportData, scale: float, offset_m: float) -> SupportData:
    """The support residual after correcting the depth: the plane refitted on the table
    points moved along their rays. A pure scale keeps the normal; an offset turns it (the
    displacement ``o`` along each ray is a larger share of near points' depth)."""
    if support.points_camera is None or support.world_from_camera is None:
        return support
    p = np.asarray(support.points_camera, dtype=np.float64)
    z = p[:, 2:3]
    return support_refitted(support, p / z * (z - offset_m) / scale)


def support_refitted(support: SupportData, points_camera: np.ndarray) -> SupportData:
    """``support`` with its table inliers replaced by ``points_camera`` (N, 3, camera frame)
    and the plane refitted on them in the world (least squares; normal towards the camera)."""
    q = np.asarray(points_camera, dtype=np.float64)
    t = np.asarray(support.world_from_camera, dtype=np.float64)
    w = q @ t[:3, :3].T + t[:3, 3]
    centre, normal = least_squares_plane(w)
    if normal @ (np.asarray(support.camera_center) - centre) < 0:
        normal = -normal
    return replace(support, normal=normal, point=centre, points_camera=q)
