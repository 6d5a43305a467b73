"""Objects whose reconstruction jumped in a diagnose rerun further than their data moved.

An effect corrects the observation (depth, camera), so every object's observed points move
(a 4 % depth scale moves an object 60 cm away by about 24 mm) and its reconstruction should
move with them. When the rerun puts an object's reconstruction somewhere else, by much
more than its points moved, the fit itself flipped: a prior seen by few points lands on
another of its near-equal registrations, or the choice between prior and completion goes
the other way. That change is not the effect's doing, and it can make the twin worse
while the residual the effect claimed falls. The loop (r2s/runner/diagnose_loop.py)
reverts such a step and says which object jumped.

Per object in both states: ``jump = |(c_after - c_before) - (p_after - p_before)|``, ``c``
the centroid of its mesh's vertices at its pose, ``p`` the centroid of its observed points
(``observed_points`` of the state, world frame, metres). A frame change (a corrected camera
rotation) moves both alike and cancels.

Not every jump is a loss: a correct depth scale can bring a prior that floated 35 mm above
the table down onto it (the benchmark's ``depth_scale`` seed 1: that object's centroid
error 33 -> 10 mm), or make a prior fit better than the completion that stood for it.
What no residual sees is a fit that *leaves* its support: so a jump :meth:`Jump.lifts_off`
when the object's lowest point ends farther from the support plane (either side) than it
was by more than ``LIFT_TOLERANCE_M`` (the ``dark_depth`` seed 1: a box seen by 75 points
went from 7 to 59 mm above the table, its centroid error 9 -> 46 mm).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from r2s.geometry.plane import signed_distance
from r2s.io.mesh_io import load_mesh
from r2s.io.state import ObjectState, read_state

JUMP_TOLERANCE_M = 0.02
"""A reconstruction that moved this much more than its points did jumped (m)."""
LIFT_TOLERANCE_M = 0.01
"""A jump lifts off when the lowest point's distance from the support grows by this (m)."""


@dataclass(frozen=True)
class Jump:
    """One object's jump: ``jump_m`` beyond ``points_moved_m`` (its observed points'
    centroid shift); ``num_points`` observed points; ``sources`` (before, after)."""

    object_id: int
    jump_m: float
    points_moved_m: float
    num_points: Optional[int]
    sources: tuple[str, str]
    gap_m: tuple[float, float] = (0.0, 0.0)
    """The lowest point's signed distance from the support plane, before and after (m)."""

    def lifts_off(self, tolerance_m: float = LIFT_TOLERANCE_M) -> bool:
        """The jump took the object farther from its support (module docstring)."""
        return abs(self.gap_m[1]) - abs(self.gap_m[0]) > tolerance_m

    def describe(self) -> str:
        seen = f" ({self.num_points} points)" if self.num_points else ""
        source = (f", {self.sources[0]} -> {self.sources[1]}"
                  if self.sources[0] != self.sources[1] else "")
        return (f"object {self.object_id}'s reconstruction moved {1000 * self.jump_m:.0f} mm "
                f"more than its observed points ({1000 * self.points_moved_m:.0f} mm){seen}"
                f"{source}, its lowest point {1000 * self.gap_m[0]:.0f} -> "
                f"{1000 * self.gap_m[1]:.0f} mm from the support plane")


def _centroids(stage_dir: Path, o: ObjectState, plane: tuple[np.ndarray, np.ndarray]
               ) -> Optional[tuple[np.ndarray, np.ndarray, float]]:
    """(mesh centroid, observed points' centroid, world frame; the mesh's lowest signed
    distance from ``plane`` (point, normal)); None when mesh or points are missing."""
    points = getattr(o, "observed_points", None)
    if not points or not (stage_dir / points).is_file() or not (stage_dir / o.mesh).is_file():
        return None
    pts = np.asarray(np.load(stage_dir / points), dtype=np.float64).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if not len(pts):
        return None
    mesh = load_mesh(stage_dir / o.mesh)
    verts = np.asarray(mesh.vertices, dtype=np.float64) @ o.pose[:3, :3].T + o.pose[:3, 3]
    return verts.mean(axis=0), pts.mean(axis=0), float(signed_distance(verts, *plane).min())


def reconstruction_jumps(before_stage_dir: Path, after_stage_dir: Path,
                         tolerance_m: float = JUMP_TOLERANCE_M) -> list[Jump]:
    """Objects of both stage directories (``<scene>/init``) whose reconstruction moved more
    than ``tolerance_m`` beyond their observed points (module docstring), largest first."""
    before, after = read_state(Path(before_stage_dir)), read_state(Path(after_stage_dir))
    planes = [(np.asarray(st.support.point), np.asarray(st.support.normal))
              for st in (before, after)]
    found = []
    for o in after.objects:
        try:
            b = before.object(o.id)
        except KeyError:
            continue
        cb = _centroids(Path(before_stage_dir), b, planes[0])
        ca = _centroids(Path(after_stage_dir), o, planes[1])
        if cb is None or ca is None:
            continue
        points_moved = ca[1] - cb[1]
        jump = float(np.linalg.norm((ca[0] - cb[0]) - points_moved))
        if jump > tolerance_m:
            found.append(Jump(o.id, jump, float(np.linalg.norm(points_moved)),
                              getattr(o, "num_observed_points", None), (b.source, o.source),
                              (cb[2], ca[2])))
    return sorted(found, key=lambda j: -j.jump_m)
