"""Rotations for the "gravity not perpendicular to the observed table" effects.

``world_correction`` (4, 4) is a rotation about a pivot (the camera centre): applied to
the declared world it gives the corrected world, ``x_corrected = T @ x``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from r2s.diagnose.stats.blocks import tilt_vector


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

