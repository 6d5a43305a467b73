"""Bound physopt's repairs by the observation: flag what had to move far from where it was seen.

PyBullet repairs (settling, damped rest) make a scene rest by moving objects. An object
that can only rest farther than a tolerance from its init pose (the pose registered to
the image) is probably wrong; it is flagged, with the reason, rather than silently moved.
The flag travels in the state as :data:`OBSERVATION_FLAG_KEY` and ends in the object's
``observation`` block in ``export/scene.json``.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from r2s.metrics.observation import pose_displacement

OBSERVATION_FLAG_KEY = "observation_flag"
"""Per-object key of a state: why a stage flagged the object (absent / None: not flagged)."""


def displacement_flags(init_world_from_object: Mapping[int, np.ndarray],
                       world_from_object: Mapping[int, np.ndarray],
                       centres_in_object: Mapping[int, np.ndarray], tolerance_m: float,
                       tolerance_deg: float, stage: str = "physopt"
                       ) -> tuple[dict[int, str], dict[int, tuple[float, float]]]:
    """Objects displaced beyond tolerance from their init pose.

    Parameters
    ----------
    init_world_from_object, world_from_object : id -> (4, 4) pose where it was seen and
        where it ends.
    centres_in_object : id -> (3,) object-frame point whose motion counts (mesh centroid).
    tolerance_m, tolerance_deg : the largest accepted move and turn.

    Returns
    -------
    flags : id -> reason, for the flagged objects only.
    displacement : id -> (metres, degrees) for every object with an init pose.
    """
    flags: dict[int, str] = {}
    disp: dict[int, tuple[float, float]] = {}
    for i, pose in world_from_object.items():
        if i not in init_world_from_object:
            continue
        m, deg = pose_displacement(init_world_from_object[i], pose, centres_in_object[i])
        disp[i] = (m, deg)
        parts = []
        if m > tolerance_m:
            parts.append(f"moved {1000 * m:.0f} mm (> {1000 * tolerance_m:.0f} mm)")
        if deg > tolerance_deg:
            parts.append(f"turned {deg:.0f} deg (> {tolerance_deg:.0f} deg)")
        if parts:
            flags[i] = f"{stage} {' and '.join(parts)} from where it was seen to make it rest"
    return flags, disp
