"""Push-prediction error: how well a predicted push outcome matches the observed one.

- **UCD** (the paper's measure): unilateral Chamfer distance from the observed points
  after the push (the depth after it, back-projected inside each object's mask) to the
  surface of the same object's predicted mesh at its predicted final pose; the mean over
  points, in mm. It includes the reconstruction's own shape and pose error.
- **Pose error** (where the true final poses are known): the predicted motion of an object
  (``final @ inv(initial)`` of its reconstruction) applied to the true object, against the
  true final pose: translation at the true centre of mass (mm) and rotation (degrees).
  It measures the predicted motion alone; the initial reconstruction error is not in it.

Pure functions on arrays; world frame, metres in, mm / degrees out where the name says.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
import trimesh

from r2s.geometry.camera import backproject
from r2s.metrics.proximity import surface_distances_to
from r2s.metrics.stability import rotation_angle_deg

MAX_POINTS_PER_OBJECT = 4000


def observed_points(depth_m: np.ndarray, masks: np.ndarray, K: np.ndarray,
                    world_from_camera: np.ndarray, max_points: int = MAX_POINTS_PER_OBJECT,
                    seed: int = 0) -> dict[int, np.ndarray]:
    """Back-projected points of each instance.

    Parameters
    ----------
    depth_m : (H, W) metres along the camera z axis, NaN / <= 0 = no reading.
    masks : (H, W) int instance ids, 0 = no object.
    K : (3, 3) intrinsics; world_from_camera : (4, 4) OpenCV camera to world.
    max_points : at most this many points per instance (a seeded random subset).

    Returns
    -------
    instance id -> (M, 3) world points (instances with no valid depth are left out).
    """
    rng = np.random.default_rng(seed)
    out = {}
    for oid in (int(i) for i in np.unique(masks) if i > 0):
        pts = backproject(depth_m, K, world_from_camera, mask=masks == oid)
        if len(pts) > max_points:
            pts = pts[np.sort(rng.choice(len(pts), max_points, replace=False))]
        if len(pts):
            out[oid] = pts
    return out


def unilateral_chamfer_mm(points_world: np.ndarray, mesh_world: trimesh.Trimesh) -> float:
    """Mean distance (mm) from ``points_world`` (M, 3) to the surface of ``mesh_world``."""
    return 1000.0 * float(np.mean(surface_distances_to(mesh_world, points_world)))


def push_ucd(points_by_id: dict[int, np.ndarray],
             predicted_mesh_by_id: dict[int, trimesh.Trimesh]) -> dict:
    """UCD of every observed object that has a prediction.

    Returns ``{"ucd_mm": mean over all matched points, "ucd_median_mm": median over them,
    "objects": [{"id", "ucd_mm", "points"}], "unmatched_ids": observed ids with no
    predicted mesh}``; the means are None when nothing matched.
    """
    per, all_d = [], []
    for oid, pts in sorted(points_by_id.items()):
        if oid not in predicted_mesh_by_id:
            continue
        d_mm = 1000.0 * surface_distances_to(predicted_mesh_by_id[oid], pts)
        per.append({"id": int(oid), "ucd_mm": float(d_mm.mean()), "points": int(len(pts))})
        all_d.append(d_mm)
    d = np.concatenate(all_d) if all_d else np.zeros(0)
    return {"ucd_mm": float(d.mean()) if len(d) else None,
            "ucd_median_mm": float(np.median(d)) if len(d) else None,
            "objects": per,
            "unmatched_ids": sorted(int(i) for i in points_by_id if i not in predicted_mesh_by_id)}


def motion_error(pred_initial: np.ndarray, pred_final: np.ndarray, true_initial: np.ndarray,
                 true_final: np.ndarray, com_in_true_object: Optional[np.ndarray] = None
                 ) -> tuple[float, float]:
    """Error of a predicted motion: (translation mm at the true COM, rotation deg).

    All poses (4, 4) ``world_from_object``; ``pred_*`` in the reconstruction's object
    frame, ``true_*`` in the true object's frame; ``com_in_true_object`` (3,) defaults to
    the frame origin.
    """
    motion = np.asarray(pred_final, dtype=np.float64) @ np.linalg.inv(pred_initial)
    predicted = motion @ np.asarray(true_initial, dtype=np.float64)
    true_final = np.asarray(true_final, dtype=np.float64)
    com = np.zeros(3) if com_in_true_object is None else np.asarray(com_in_true_object, float)
    p = predicted[:3, :3] @ com + predicted[:3, 3]
    t = true_final[:3, :3] @ com + true_final[:3, 3]
    return (1000.0 * float(np.linalg.norm(p - t)),
            float(rotation_angle_deg(predicted[:3, :3], true_final[:3, :3])))
