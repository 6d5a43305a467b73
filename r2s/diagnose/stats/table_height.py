"""The table's height as evidence: where the declared world puts the table.

Scene files put the world's origin on the table (``z = 0`` is its surface: the support of
``gt/scene.json`` in SCENE_FORMAT.md, the peer scene, a calibration target lying on the
table). The camera centre ``c`` is declared in that frame, so the distance from the camera
to the table is declared too: ``c . up`` for a level table. What each effect does to it:

- a depth scale ``s`` scales the scene about the camera centre: the fitted table lies at
  ``s`` times its true distance (4 % at 0.5 m: 2 cm, against a plane fit good to a tenth
  of a millimetre);
- a depth offset ``o`` moves every table point along its ray by ``o``: the fitted plane's
  distance moves by about ``o d / z`` (``d`` its distance, ``z`` the points' depth);
- a camera rotation turns the world about the camera centre: the distance is kept, but
  the table no longer passes through the origin;
- a tilted table (pivoting about the origin) keeps passing through the origin, and its
  distance from the camera changes.

So the table's distance from the camera against the distance the model declares (from
the camera centre to the plane through the origin normal to the model's up:
:attr:`r2s.diagnose.data.SupportData.height_m`) tells the depth effects their size, and
it tells a camera error (which keeps it) from a tilted table (which changes it), where the
normal alone cannot.

A world frame that is not on the table (a robot's base, a room corner) says nothing: the
evidence is used only when the fitted table passes near the origin, or near the declared
camera height once levelled (:func:`declares_table`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from r2s.diagnose.data import SupportData
from r2s.geometry.plane import least_squares_plane

DECLARED_SHARE = 0.15
"""The table counts as declared when its height at the origin, or its camera distance
against the declared camera height, is within this share of the camera distance: depth
biases of up to 15 % and camera errors of a few degrees stay in; a world frame on the
floor or on a robot's base (tens of centimetres away) is out."""


def declares_table(support: SupportData) -> bool:
    """Whether the declared world evidently puts the table through its origin: the fitted
    plane's distance from the camera is near the declared one, or the plane passes near the
    origin (a tilted table)."""
    dist = support.camera_distance_m
    through_origin = abs(support.plane_distance_m(support.anchor_world))
    closest = min(abs(support.height_m), through_origin)
    return bool(dist > 0 and closest <= DECLARED_SHARE * dist)


EVIDENCE_POINTS = 1500
"""Table inliers the depth fits refit the plane on (a seeded subsample)."""


@dataclass(frozen=True)
class TableHeightEvidence:
    """The table's height as one observation of a depth bias (s, o).

    points_camera : (N, 3) table inliers, camera frame, m.
    distance_m : camera centre to the fitted plane, m.
    model_distance_m : camera centre to the model's table, m.
    mean_inverse_depth : mean of ``1 / z`` over the inliers (camera z), 1/m.
    sigma_m : noise level of the height, m.
    """

    points_camera: np.ndarray = field(repr=False)
    distance_m: float
    model_distance_m: float
    mean_inverse_depth: float
    sigma_m: float

    def residual_m(self, scale: float, offset_m: float) -> float:
        """The height left after correcting the depth by ``(z - o) / s``: the inliers
        moved along their rays to ``(z - o) / s`` and the plane refitted on them (an
        offset turns it as well as moving it)."""
        p = self.points_camera
        z = p[:, 2:3]
        q = p * ((z - offset_m) / scale) / z
        centre, normal = least_squares_plane(q)
        return float(abs(normal @ centre) - self.model_distance_m)

    def information(self, fit_scale: bool) -> float:
        """Fisher information of the height about ``log s`` (``fit_scale``) or about ``o``
        (a plane at distance d moves by about ``d <1/z>`` per metre of offset)."""
        slope = self.distance_m if fit_scale else self.distance_m * self.mean_inverse_depth
        return float((slope / self.sigma_m) ** 2)


def height_evidence(support: SupportData | None, seed: int = 0) -> TableHeightEvidence | None:
    """The evidence of ``support`` when its height is used, else None."""
    if support is None or not support.height_used or support.points_camera is None:
        return None
    p = np.asarray(support.points_camera, dtype=np.float64)
    p = p[p[:, 2] > 0]
    if len(p) < 3:
        return None
    if len(p) > EVIDENCE_POINTS:
        p = p[np.random.default_rng(seed).choice(len(p), EVIDENCE_POINTS, replace=False)]
    dist = support.camera_distance_m
    return TableHeightEvidence(points_camera=p, distance_m=dist,
                               model_distance_m=dist - support.height_m,
                               mean_inverse_depth=float(np.mean(1.0 / p[:, 2])),
                               sigma_m=float(support.height_sigma_m))


def with_height(support: SupportData, height_m: float) -> SupportData:
    """``support`` with its plane (and inliers) moved along its normal so that its
    ``height_m`` is ``height_m``: a draw of what noise alone gives, for the noise bar."""
    n = np.asarray(support.normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    shift = support.height_m - float(height_m)     # towards the camera by this much
    point = np.asarray(support.point, dtype=np.float64) + shift * n
    pts = support.points_camera
    if pts is not None and support.world_from_camera is not None:
        rot = np.asarray(support.world_from_camera, dtype=np.float64)[:3, :3]
        pts = np.asarray(pts, dtype=np.float64) + shift * (rot.T @ n)
    return replace(support, point=point, points_camera=pts)
