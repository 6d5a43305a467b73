"""Rotations for the "gravity not perpendicular to the observed table" effects.

``world_correction`` (4, 4) is a rotation about a pivot (the camera centre): applied to
the declared world it gives the corrected world, ``x_corrected = T @ x``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from r2s.diagnose.blocks import tilt_vector


def correction_to_level(up: np.ndarray, normal: np.ndarray, pivot: np.ndarray) -> np.ndarray:
    """(4, 4) the smallest rotation about ``pivot`` taking ``normal`` to ``up``."""
    rot = Rotation.from_rotvec(-tilt_vector(up, normal)).as_matrix()
    out = np.eye(4)
    out[:3, :3] = rot
    out[:3, 3] = np.asarray(pivot, dtype=np.float64) - rot @ np.asarray(pivot, dtype=np.float64)
    return out


def angle_axis(rot: np.ndarray) -> tuple[float, np.ndarray]:
    """(angle in degrees, unit axis) of a (3, 3) rotation (axis +z for the identity)."""
    vec = Rotation.from_matrix(np.asarray(rot, dtype=np.float64)[:3, :3]).as_rotvec()
    angle = float(np.linalg.norm(vec))
    axis = vec / angle if angle > 1e-12 else np.array([0.0, 0.0, 1.0])
    return float(np.degrees(angle)), axis


def camera_or_table(first_round, kept: list, prior_odds: float) -> dict | None:
    """The camera-or-table choice of the first ranking, for the report: which of
    ``camera_rotation`` / ``table_tilt`` was named (or led, when neither was kept), the
    other as the alternative, their scores, the prior, and gravity in the declared world
    frame (with a camera correction the exported world is the corrected one, where gravity
    is -z; in the declared frame it is the correction's inverse applied to -z)."""
    if first_round is None:
        return None
    fits = {f.effect: f for f in first_round.fits
            if f.effect in ("camera_rotation", "table_tilt") and f.identifiable}
    if len(fits) < 2:
        return None
    names = [f.effect for f in kept]
    if "camera_rotation" in names or "table_tilt" in names:
        choice = "camera_rotation" if "camera_rotation" in names else "table_tilt"
    elif fits["camera_rotation"].size is None or fits["camera_rotation"].size < 0.5:
        return None
    else:
        choice = min(fits, key=lambda n: fits[n].score)
    other = "table_tilt" if choice == "camera_rotation" else "camera_rotation"
    out = {"choice": choice, "alternative": other, "kept": choice in names,
           "score": {n: f.score for n, f in fits.items()},
           "delta_bic": {n: f.delta_bic for n, f in fits.items()},
           "prior_odds_camera_to_table": prior_odds,
           "why": (f"prior odds {prior_odds:g}:1 for a camera error (table_tilt carries "
                   f"{2 * np.log(prior_odds):.2f} BIC units); scores camera "
                   f"{fits['camera_rotation'].score:.1f}, table {fits['table_tilt'].score:.1f}")}
    corr = fits["camera_rotation"].params.get("world_correction")
    if choice == "camera_rotation" and corr is not None:
        rot = np.asarray(corr, dtype=np.float64)[:3, :3]
        out["gravity_declared_world"] = (rot.T @ np.array([0.0, 0.0, -9.81])).tolist()
        out["gravity_exported_world"] = [0.0, 0.0, -9.81]
    return out
