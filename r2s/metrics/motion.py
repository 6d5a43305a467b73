"""Which objects moved during a rollout, and by how much (pure numpy on a Trajectory).

An object *moved* when its centre of mass travelled at least ``moved_translation_m`` or it
turned at least ``moved_rotation_deg`` between the first and the last sample. These limits
are far below the judge's stability thresholds (5 cm, 5 deg): the pictures and the viewer
point out every visible motion, and say separately which objects the judge calls unstable.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from r2s.metrics.stability import rotation_angle_deg
from r2s.sim.rollout import Trajectory

MOVED_TRANSLATION_M = 0.005
"""Default: a COM displacement of 5 mm or more counts as motion."""

MOVED_ROTATION_DEG = 2.0
"""Default: a turn of 2 degrees or more counts as motion."""


@dataclass(frozen=True)
class ObjectMotion:
    """Motion of one object between the first and the last sample of a rollout.

    ``com_start_m`` / ``com_end_m`` : (3,) world COM positions, metres.
    """

    id: int
    label: str
    displacement_mm: float
    rotation_deg: float
    com_start_m: np.ndarray
    com_end_m: np.ndarray
    moved: bool

    @property
    def caption(self) -> str:
        """``"3 mug: 12.4 mm, 3.1 deg"``: what a picture writes next to the object."""
        name = f"{self.id} {self.label}".strip()
        return f"{name}: {self.displacement_mm:.1f} mm, {self.rotation_deg:.1f} deg"


def object_motions(traj: Trajectory, labels: Mapping[int, str] | None = None,
                   moved_translation_m: float = MOVED_TRANSLATION_M,
                   moved_rotation_deg: float = MOVED_ROTATION_DEG) -> list[ObjectMotion]:
    """One :class:`ObjectMotion` per object of ``traj``, in ``traj.ids`` order."""
    labels = labels or {}
    if len(traj.ids) == 0:
        return []
    com = traj.com_world_m                                    # (T, N, 3)
    disp_m = np.linalg.norm(com[-1] - com[0], axis=-1)        # (N,)
    rot = traj.world_from_object[..., :3, :3]
    turn_deg = rotation_angle_deg(rot[0], rot[-1])            # (N,)
    out = []
    for k, obj_id in enumerate(traj.ids):
        out.append(ObjectMotion(
            id=int(obj_id), label=str(labels.get(int(obj_id), "")),
            displacement_mm=float(1000.0 * disp_m[k]), rotation_deg=float(turn_deg[k]),
            com_start_m=com[0, k].copy(), com_end_m=com[-1, k].copy(),
            moved=bool(disp_m[k] >= moved_translation_m or turn_deg[k] >= moved_rotation_deg),
        ))
    return out


def moved_objects(motions: list[ObjectMotion]) -> list[ObjectMotion]:
    """The objects that moved, the largest displacement first."""
    return sorted((m for m in motions if m.moved), key=lambda m: -m.displacement_mm)
