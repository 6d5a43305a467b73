"""Bound physopt's repairs by the observation: flag what had to move far from where it was seen.

PyBullet repairs (settling, damped rest) make a scene rest by moving objects. An object
that can only rest farther than a tolerance from its init pose (the pose registered to
the image) is probably wrong; it is flagged, with the reason, rather than silently moved.
The flag travels in the state as :data:`OBSERVATION_FLAG_KEY` and ends in the object's
``observation`` block in ``export/scene.json``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from r2s.io.paths import ScenePaths
from r2s.io.state import SceneState, read_state
from r2s.metrics.observation import pose_displacement
from r2s.scene_model import corrected_state

OBSERVATION_FLAG_KEY = "observation_flag"
"""Per-object key of a state: why a stage flagged the object (absent / None: not flagged)."""
SEEN_POSE_KEY = "seen_world_from_object"
"""Per-object key of a state: the (4, 4) pose where the object's current mesh was seen,
when that is not init's pose (physopt swapped a prior for init's completion of it)."""


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


@dataclass(frozen=True)
class ObservationBound:
    """Where each object was seen, and how far a repair may carry it from there.

    seen : id -> (4, 4) init pose (registered to the image); centres : id -> (3,)
    object-frame point whose motion counts (mesh centroid); an object without a seen pose
    is unbounded.
    """

    seen: Mapping[int, np.ndarray]
    centres: Mapping[int, np.ndarray]
    tolerance_m: float
    tolerance_deg: float

    def excess(self, oid: int, pose: np.ndarray) -> float:
        """max(move / tolerance_m, turn / tolerance_deg) of ``pose`` from where ``oid``
        was seen: <= 1 within tolerance (0 for an object without a seen pose)."""
        if oid not in self.seen:
            return 0.0
        m, deg = pose_displacement(self.seen[oid], pose, self.centres[oid])
        return max(m / self.tolerance_m, deg / self.tolerance_deg)

    def allows(self, oid: int, start: np.ndarray, end: np.ndarray) -> bool:
        """A repair may take ``oid`` from ``start`` to ``end``: it ends within tolerance,
        or no farther from the observation than it started (it may come back)."""
        after = self.excess(oid, end)
        return after <= 1.0 or after <= self.excess(oid, start) + 1e-9

    def beyond(self, poses: Mapping[int, np.ndarray]) -> list[int]:
        """Ids whose pose is beyond tolerance from where they were seen."""
        return [i for i, pose in poses.items() if self.excess(i, pose) > 1.0]


def seen_poses(paths: ScenePaths, state: SceneState, model: dict) -> dict[int, np.ndarray]:
    """id -> the pose where the object was seen: init's (as the scene's model corrects it),
    else the given state's."""
    seen = state
    if (paths.stage_dir("init") / "state.json").is_file():
        seen = corrected_state(read_state(paths.stage_dir("init")), model)
    return {o.id: np.asarray(o.pose, dtype=float) for o in seen.objects}
