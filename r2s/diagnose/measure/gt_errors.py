"""Ground-truth errors of a reconstruction that the effects can change (benchmark scenes).

From the judge's ``evaluate/metrics.json`` (pose, Chamfer distance, stability) and from
``export/scene.json`` against ``gt/scene.json``:

- ``com_error_mm``: distance between the reconstructed and true centre of mass, world
  frame, mean over objects matched by id (and ``com_error_max_mm``);
- ``support_normal_error_deg``: angle between reconstructed and true table normals;
- ``gravity_error_deg``: angle between reconstructed and true gravity;
- ``table_gravity_error_deg``: difference of the angle between gravity and the table
  normal (frame independent: what physics feels);
- ``friction_error``: mean absolute difference of the per-body friction coefficients.

Pure functions on the parsed models.
"""

from __future__ import annotations

from typing import Any, Optional

import numpy as np

from r2s.io.scene_json import ExportScene, GtScene

METRIC_KEYS: tuple[str, ...] = ("centroid_error_mm", "rotation_error_deg", "chamfer_mm",
                                "fscore", "iou", "stability_ratio", "mean_linear_speed_mps")
"""Keys copied from evaluate/metrics.json."""


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    c = a @ b / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-18)
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def _com_world(pose: list, com: list) -> np.ndarray:
    t = np.asarray(pose, dtype=np.float64)
    return t[:3, :3] @ np.asarray(com, dtype=np.float64) + t[:3, 3]


def export_gt_errors(export: ExportScene, gt: GtScene) -> dict[str, Any]:
    """Scene-level errors of ``export`` against ``gt`` (see the module docstring)."""
    gt_by_id = {o.id: o for o in gt.objects}
    com_err, fric_err, per_object = [], [], []
    for o in export.objects:
        g = gt_by_id.get(o.id)
        if g is None:
            continue
        e = float(np.linalg.norm(_com_world(o.world_from_object, o.com_in_object)
                                 - _com_world(g.world_from_object, g.com_in_object)) * 1000.0)
        com_err.append(e)
        fric_err.append(abs(float(o.friction) - float(g.friction)))
        per_object.append({"id": o.id, "com_error_mm": e, "friction": float(o.friction),
                           "gt_friction": float(g.friction)})
    n_r, n_t = np.asarray(export.support.normal), np.asarray(gt.support.normal)
    g_r, g_t = np.asarray(export.gravity), np.asarray(gt.gravity)
    return {
        "com_error_mm": float(np.mean(com_err)) if com_err else None,
        "com_error_max_mm": float(np.max(com_err)) if com_err else None,
        "support_normal_error_deg": _angle_deg(n_r, n_t),
        "gravity_error_deg": _angle_deg(g_r, g_t),
        "table_gravity_error_deg": abs(_angle_deg(-g_r, n_r) - _angle_deg(-g_t, n_t)),
        "friction_error": float(np.mean(fric_err)) if fric_err else None,
        "objects": per_object,
    }


def state_gt_errors(posed_centroids: dict[int, np.ndarray], support_normal: np.ndarray,
                    gt: GtScene, gt_centroids: dict[int, np.ndarray]) -> dict[str, Any]:
    """Pose errors of a state without an export: surface-centroid distance (mm) per object
    matched by id (mean, median, max), and the support normal's angle to the true one (deg).

    ``posed_centroids`` / ``gt_centroids``: object id -> (3,) world surface centroid.
    """
    errs = {i: float(np.linalg.norm(np.asarray(c) - np.asarray(gt_centroids[i])) * 1000.0)
            for i, c in posed_centroids.items() if i in gt_centroids}
    return {"state_centroid_error_mm": float(np.mean(list(errs.values()))) if errs else None,
            "state_centroid_error_median_mm": float(np.median(list(errs.values())))
            if errs else None,
            "state_centroid_error_max_mm": float(np.max(list(errs.values()))) if errs else None,
            "state_support_normal_error_deg": _angle_deg(support_normal, gt.support.normal)}


def metrics_subset(metrics: Optional[dict]) -> dict[str, Any]:
    """The judge's scene-level numbers diagnose reports (None where absent)."""
    metrics = metrics or {}
    return {k: metrics.get(k) for k in METRIC_KEYS}
