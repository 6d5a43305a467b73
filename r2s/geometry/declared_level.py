"""Is the declared camera pose grossly off? The table's tilt in the declared world.

Conventions: world frame z up (SCENE_FORMAT.md), OpenCV camera frame, ``world_from_camera``
as declared in ``input/camera.json``. The support is found without any assumption about
where up is: the plane the objects stand on (:func:`r2s.geometry.plane.fit_support_plane`
with no tilt limit), its normal pointing at the camera.

A table tilted by a few degrees is a question for ``r2s diagnose`` (a camera calibration
error or a tilted table, docs/diagnose.md section 5). A support tilted by more than
:data:`GROSS_TILT_DEG` in the declared world cannot hold the objects seen resting on it
(at 15 degrees a friction of 0.27 is needed), so the declared pose is wrong: the identity
of a user who does not know the camera's extrinsics, or axes in another convention.
:func:`gross_level_correction` gives the smallest rotation about the camera centre that
levels the table; :func:`r2s.scene_model.corrected_input` applies it like a kept
``camera_rotation``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
from scipy.spatial.transform import Rotation

from r2s.geometry.camera import backproject, instance_points
from r2s.geometry.plane import FLOATING_M, fit_support_plane, standing_gap_m

GROSS_TILT_DEG = 15.0
"""Above this angle between the table's normal and the declared +z the declared camera pose,
not the table, is taken to be wrong."""
UP = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class DeclaredLevel:
    """The support plane against the declared vertical.

    normal_world : (3,) unit normal of the support, declared world frame, towards the camera.
    tilt_deg : its angle to the declared +z, degrees.
    """

    normal_world: np.ndarray
    tilt_deg: float


def declared_level(depth_m: np.ndarray, masks: np.ndarray, K: np.ndarray,
                   world_from_camera: np.ndarray, object_ids: list[int],
                   max_points: int = 30000, seed: int = 0) -> Optional[DeclaredLevel]:
    """The support's tilt in the declared world (None when too few background readings).

    depth_m : (H, W) metres, NaN / <= 0 = none; masks : (H, W) instance ids, 0 = background;
    K : (3, 3); world_from_camera : (4, 4); object_ids : the instances standing on it."""
    rng = np.random.default_rng(seed)
    background = backproject(depth_m, K, world_from_camera, np.asarray(masks) == 0)
    if len(background) < 100:
        return None
    if len(background) > max_points:
        background = background[rng.choice(len(background), size=max_points, replace=False)]
    objects = instance_points(depth_m, K, world_from_camera, masks, object_ids, rng, 2000)
    viewpoint = np.asarray(world_from_camera)[:3, 3]
    # a level support the objects stand on first: a wall or a floor that is larger than the
    # table must not turn a correctly declared world on its side
    for limit in (GROSS_TILT_DEG, None):
        try:
            plane = fit_support_plane(background, objects, iterations=300, seed=seed,
                                      viewpoint=viewpoint, max_tilt_deg=limit)
        except ValueError:
            continue
        tilt = float(np.degrees(np.arccos(np.clip(plane.normal @ UP, -1.0, 1.0))))
        gap = standing_gap_m(plane, objects)
        if limit is None or (tilt <= limit and not gap > FLOATING_M):
            return DeclaredLevel(normal_world=plane.normal, tilt_deg=tilt)
    return None


def gross_level_correction(level: Optional[DeclaredLevel], camera_centre: np.ndarray,
                           limit_deg: float = GROSS_TILT_DEG) -> Optional[np.ndarray]:
    """(4, 4) ``corrected_world_from_world``: the smallest rotation about the camera centre
    that takes the support's normal to +z, when its tilt exceeds ``limit_deg`` (else None).
    """
    if level is None or level.tilt_deg <= limit_deg:
        return None
    n = np.asarray(level.normal_world, dtype=np.float64)
    n = n / np.linalg.norm(n)
    axis = np.cross(n, UP)
    if np.linalg.norm(axis) < 1e-9:  # upside down: any horizontal axis
        axis = np.array([1.0, 0.0, 0.0])
    axis = axis / np.linalg.norm(axis)
    angle = float(np.arccos(np.clip(n @ UP, -1.0, 1.0)))
    rot = Rotation.from_rotvec(angle * axis).as_matrix()
    pivot = np.asarray(camera_centre, dtype=np.float64)
    out = np.eye(4)
    out[:3, :3] = rot
    out[:3, 3] = pivot - rot @ pivot
    return out
