"""Plausibility checks that catch unit and scale mistakes before they become a scene.

Each check returns a one-line problem (or None); the caller decides whether it is an error
or a warning that is also flagged in the stage summary. Thresholds are module constants.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
import trimesh

MIN_PRIOR_FACES = 4
"""Fewer faces than a tetrahedron cannot bound a volume."""

MIN_THICKNESS_RATIO = 1e-3
"""A prior whose smallest bounding-box side is below this fraction of its largest is flat."""

PRIOR_SIZE_WARN_RATIO = 3.0
"""Prior size / observed size beyond this factor (either way) gets a warning."""

PRIOR_SIZE_ERROR_RATIO = 30.0
"""... and beyond this factor an error: the prior is in other units (mm or cm vs m)."""

SCENE_PRIOR_RATIO_RANGE = (0.85, 2.2)
"""The median over a scene's priors of prior size / observed size (:func:`prior_size_ratio`)
outside this range gets a warning: every object seen larger (or smaller) than its prior
says the depth's scale is off. Scenes with a right depth unit gave medians of 1.08-1.53
(20 synthesised clean scenes, the 10 realistic and held-out prior scenes, the 10 YCB
scenes, the seed demo; measured on each mask's raw points); the depth read 2x long, 0.71
as init measures it (docs/diagnose.md)."""

ICP_FITNESS_FLOOR = 0.3
"""Fraction of the observed points a fitted object must explain; below: a warning."""


def robust_extent_m(points: np.ndarray) -> float:
    """Diagonal (m) of the 2nd-98th percentile box of (N, 3) points (stray points aside)."""
    pts = np.asarray(points, dtype=float)
    if len(pts) < 2:
        return 0.0
    lo, hi = np.percentile(pts, [2, 98], axis=0)
    return float(np.linalg.norm(hi - lo))


def mesh_extent_m(mesh: trimesh.Trimesh) -> float:
    """Diagonal of the mesh's axis-aligned bounding box, in the mesh's units."""
    v = np.asarray(mesh.vertices, dtype=float)
    return float(np.linalg.norm(v.max(axis=0) - v.min(axis=0))) if len(v) else 0.0


def degenerate_prior(mesh: trimesh.Trimesh) -> Optional[str]:
    """Why the prior cannot be an object's surface (too few faces, flat, non-finite)."""
    faces = int(len(mesh.faces))
    if faces < MIN_PRIOR_FACES:
        return f"degenerate prior: {faces} face{'' if faces == 1 else 's'} (need at least " \
               f"{MIN_PRIOR_FACES} to bound a volume)"
    v = np.asarray(mesh.vertices, dtype=float)
    if not np.all(np.isfinite(v)):
        return "degenerate prior: non-finite vertex coordinates"
    sides = v.max(axis=0) - v.min(axis=0)
    if sides.max() <= 0 or sides.min() < MIN_THICKNESS_RATIO * sides.max():
        return (f"degenerate prior: flat (bounding box {sides[0]:.3g} x {sides[1]:.3g} x "
                f"{sides[2]:.3g}), not a volume")
    return None


def prior_size_ratio(mesh: trimesh.Trimesh, observed_points: np.ndarray) -> float:
    """Prior bounding-box diagonal / robust diagonal of the observed points (a partial view
    sees part of the object, so a right prior gives about 1-2)."""
    observed = robust_extent_m(observed_points)
    return mesh_extent_m(mesh) / observed if observed > 0 else float("inf")


def prior_size_problem(mesh: trimesh.Trimesh, observed_points: np.ndarray
                       ) -> tuple[Optional[str], bool]:
    """(problem, is_error) for a prior whose size disagrees with the observation."""
    ratio = prior_size_ratio(mesh, observed_points)
    size, seen = mesh_extent_m(mesh), robust_extent_m(observed_points)
    if 1 / PRIOR_SIZE_WARN_RATIO <= ratio <= PRIOR_SIZE_WARN_RATIO:
        return None, False
    text = (f"prior is {ratio:.3g}x the observed size ({size:.3g} vs {seen:.3g} m across)")
    if ratio > PRIOR_SIZE_ERROR_RATIO or ratio < 1 / PRIOR_SIZE_ERROR_RATIO:
        hint = ("; is it in millimetres? priors must be in metres" if ratio > 300 else
                "; is it in centimetres? priors must be in metres" if ratio > 30 else
                "; is it in other units? priors must be in metres")
        return text + hint, True
    return text, False


def priors_disagree_with_depth(ratios: list[float]) -> Optional[str]:
    """A warning when the scene's priors, taken together, are another size than what the
    depth shows (``ratios``: per prior, :func:`prior_size_ratio`; at least 2), else None.
    One prior may be wrong; all of them wrong the same way is the depth's scale."""
    if len(ratios) < 2:
        return None
    median = float(np.median(ratios))
    lo, hi = SCENE_PRIOR_RATIO_RANGE
    if lo <= median <= hi:
        return None
    seen = "larger" if median < lo else "smaller"
    return (f"the {len(ratios)} priors are {median:.2g}x the observed size (median, outside "
            f"the {lo:g}-{hi:g} of a right depth unit): the objects are seen {seen} than "
            "their priors. Is camera.json's depth_unit_m right?")


def low_fitness(fitness: float) -> Optional[str]:
    if not np.isfinite(fitness) or fitness < ICP_FITNESS_FLOOR:
        return (f"fit explains {fitness:.2f} of the observed points (floor "
                f"{ICP_FITNESS_FLOOR:g}); the pose is probably wrong")
    return None


def larger_than_table(object_extent_m: float, table_extent_m: float) -> Optional[str]:
    if table_extent_m > 0 and object_extent_m > table_extent_m:
        return (f"object is {object_extent_m:.3g} m across, larger than the visible table "
                f"({table_extent_m:.3g} m); a unit mistake?")
    return None
