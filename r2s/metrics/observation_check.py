"""Flag objects that do not look like what the camera saw.

A reconstruction that rests but sits somewhere else than where the object was seen is
worse than one that wobbles, because nothing warns the user. :func:`check_observation`
measures a posed scene against its input view (:mod:`r2s.metrics.observation`) and flags
each object that

* moved farther than a tolerance from its init pose (where it was seen), or
* covers too little of its own mask (silhouette IoU below ``min_iou`` for a mask of at
  least ``LARGE_MASK_PX`` pixels), or
* lost by its own move a large share of the overlap with its mask that it had where it
  was seen (IoU below ``min_iou_kept`` times the IoU it has when it alone is put back at its init
  pose, ``iou_seen``; any mask size: a 30 mm sliver moved 7 mm is far from where it was
  seen though within ``displacement_m``), or
* fills space the camera saw empty (free-space violation above ``max_free_space``), or
* was flagged by an earlier stage (``earlier_flags``, e.g. physopt's repairs).

The per-object result is the ``observation`` block of ``export/scene.json``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from r2s.metrics.observation import LARGE_MASK_PX, SceneObservation, observe_scene


SEEN_TOLERANCE_M = 0.02
"""How far (m) an object may end from where it was seen (its init pose) before it is flagged;
physopt's observation-bounded repairs and export's flags both default to it."""
SEEN_TOLERANCE_DEG = 15.0
"""... and how far it may turn, degrees."""


@dataclass(frozen=True)
class FlagTolerances:
    """When an object is flagged (lengths in metres, angles in degrees)."""

    displacement_m: float = SEEN_TOLERANCE_M
    displacement_deg: float = SEEN_TOLERANCE_DEG
    min_iou: float = 0.5
    max_free_space: float = 0.5
    min_iou_kept: float = 0.75
    min_iou_seen: float = 0.3
    """The IoU-kept test applies to objects that matched their mask at least this well
    where they were seen."""


def _round(v: Optional[float], digits: int) -> Optional[float]:
    return None if v is None or not np.isfinite(v) else round(float(v), digits)


def displacement_reason(displacement_m: Optional[float], displacement_deg: Optional[float],
                        tol: FlagTolerances) -> Optional[str]:
    """Why a displacement from the init pose is too large, or None when it is not."""
    parts = []
    if displacement_m is not None and displacement_m > tol.displacement_m:
        parts.append(f"moved {1000 * displacement_m:.0f} mm (> {1000 * tol.displacement_m:.0f} mm)")
    if displacement_deg is not None and displacement_deg > tol.displacement_deg:
        parts.append(f"turned {displacement_deg:.0f} deg (> {tol.displacement_deg:.0f} deg)")
    return " and ".join(parts) + " from where it was seen" if parts else None


def _iou_lost(iou: Optional[float], iou_seen: Optional[float],
              tol: FlagTolerances) -> Optional[str]:
    """Why an object's own move since its init pose lost it a large share of its overlap
    with its mask (``iou`` against ``iou_seen``), or None."""
    if iou_seen is None or iou_seen < tol.min_iou_seen:
        return None
    now = iou or 0.0
    if now >= tol.min_iou_kept * iou_seen:
        return None
    return (f"silhouette IoU fell from {iou_seen:.2f} where it was seen to {now:.2f} "
            f"(< {tol.min_iou_kept:.0%} of it)")


@dataclass
class ObservationCheck:
    """The measured scene, the ``observation`` block per id and one warning per flag."""

    scene: SceneObservation
    blocks: dict[int, dict]
    warnings: list[str]

    @property
    def flagged(self) -> list[int]:
        return [i for i, b in self.blocks.items() if b["flagged"]]


def check_observation(meshes_world: Sequence, ids: Sequence[int], K: np.ndarray,
                      world_from_camera: np.ndarray, depth_m: np.ndarray, masks: np.ndarray,
                      world_from_object: dict[int, np.ndarray],
                      init_world_from_object: Optional[dict[int, np.ndarray]],
                      centres_in_object: dict[int, np.ndarray],
                      tolerances: FlagTolerances = FlagTolerances(),
                      earlier_flags: Optional[dict[int, str]] = None,
                      mask_ids: Optional[Sequence[int]] = None,
                      support: Optional[tuple[np.ndarray, np.ndarray]] = None) -> ObservationCheck:
    """Measure and flag every object (arguments as :func:`observe_scene`).

    ``earlier_flags``: id -> reason for objects an earlier stage flagged. An instance of
    ``mask_ids`` without an object gets a warning line and no block.
    """
    scene = observe_scene(meshes_world, ids, K, world_from_camera, depth_m, masks,
                          init_world_from_object, world_from_object, centres_in_object,
                          mask_ids=mask_ids, support=support)
    earlier = earlier_flags or {}
    blocks: dict[int, dict] = {}
    warnings: list[str] = []
    for o in scene.objects:
        if o.missing:
            warnings.append(f"instance {o.id} of the masks ({o.mask_px} px) has no object in "
                            "the twin")
            continue
        reasons = []
        if o.id in earlier:
            reasons.append(earlier[o.id])
        moved = displacement_reason(o.displacement_m, o.displacement_deg, tolerances)
        if moved and not any("from where it was seen" in r for r in reasons):
            reasons.append(moved)
        if o.mask_px >= LARGE_MASK_PX and (o.iou or 0.0) < tolerances.min_iou:
            reasons.append(f"silhouette IoU {o.iou or 0.0:.2f} < {tolerances.min_iou:.2f}")
        kept = _iou_lost(o.iou, o.iou_seen, tolerances)
        if kept:
            reasons.append(kept)
        if o.free_space_violation is not None and o.free_space_violation > tolerances.max_free_space:
            reasons.append(f"fills space the camera saw empty ({o.free_space_violation:.2f} of "
                           f"its mask area > {tolerances.max_free_space:.2f})")
        blocks[o.id] = {
            "iou": _round(o.iou, 4), "iou_seen": _round(o.iou_seen, 4),
            "ucd_mm": _round(o.ucd_mm, 3),
            "ucd_above_support_mm": _round(o.ucd_above_support_mm, 3),
            "free_space_violation": _round(o.free_space_violation, 4),
            "displacement_m": _round(o.displacement_m, 5),
            "displacement_deg": _round(o.displacement_deg, 3),
            "flagged": bool(reasons), "reason": "; ".join(reasons) if reasons else None,
        }
        if reasons:
            warnings.append(f"object {o.id}: {'; '.join(reasons)}")
    return ObservationCheck(scene=scene, blocks=blocks, warnings=warnings)
