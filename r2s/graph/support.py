"""Who supports whom: broad phase, then the support likelihood H = (1 - d_gap)(1 - d_com).

For a child c and a candidate parent p with upward plane k:

* ``gap_m``: |lowest height of c's surface samples that lie over plane k's polygon minus
  the plane's height|; ``d_gap = clip(gap_m / gap_scale_m, 0, 1)``.
* ``com_distance_m``: horizontal distance from c's centre of mass to p's footprint
  (0 inside); ``d_com = clip(com_distance_m / r_c, 0, 1)`` with r_c the child's footprint
  radius (so a COM one child-size off the parent gives H = 0).

The table (node 0) is always a candidate: its gap is the child's lowest height above the
support plane among the samples not over the footprint of another object below the child
(the table cannot touch what another object shadows; if everything is shadowed, d_gap = 1),
and d_com = 0 (the plane is unbounded).

Broad phase for an object parent: its top is below the child's top, its bottom is below
the child's bottom, and the two footprints overlap. Because a parent's top is strictly
lower than its child's, support edges can never form a cycle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from r2s.graph.nodes import GravityFrame, ObjectNode, footprint_radius_m
from r2s.graph.polygon import contains, convex_overlap, distance_to_polygon
from r2s.graph.schema import SupportEdge

TABLE_ID = 0


@dataclass(frozen=True)
class SupportParams:
    """Thresholds of the support search (see the module docstring)."""

    gap_scale_m: float = 0.05
    min_com_scale_m: float = 0.005
    footprint_overlap_tol_m: float = 0.002
    min_support_likelihood: float = 0.25
    max_support_gap_m: float = 0.01


def _candidate(child: int, parent: int, likelihood: float, d_gap: float, d_com: float,
               gap_m: float, com_distance_m: float, plane_height_m: float) -> SupportEdge:
    """A support candidate, not (yet) in the tree."""
    return SupportEdge(child=child, parent=parent, likelihood=float(likelihood),
                       d_gap=float(d_gap), d_com=float(d_com), gap_m=float(gap_m),
                       com_distance_m=float(com_distance_m),
                       plane_height_m=float(plane_height_m))


def is_broad_phase_candidate(child: ObjectNode, parent: ObjectNode, tol_m: float) -> bool:
    """The parent lies below the child and their footprints overlap."""
    if parent.id == child.id:
        return False
    if not parent.top_height_m < child.top_height_m:
        return False
    if not parent.bottom_height_m < child.bottom_height_m + tol_m:
        return False
    return convex_overlap(child.footprint_uv_m, parent.footprint_uv_m, tol=tol_m)


def _likelihood(gap_m: float, com_distance_m: float, com_scale_m: float,
                params: SupportParams) -> tuple[float, float, float]:
    d_gap = float(np.clip(abs(gap_m) / params.gap_scale_m, 0.0, 1.0))
    d_com = float(np.clip(com_distance_m / com_scale_m, 0.0, 1.0))
    return (1.0 - d_gap) * (1.0 - d_com), d_gap, d_com


def object_candidate(child: ObjectNode, parent: ObjectNode, frame: GravityFrame,
                     params: SupportParams) -> SupportEdge | None:
    """Best plane of ``parent`` for ``child`` (None if no plane lies under the child)."""
    uv = frame.project(child.samples_world_m)
    h = frame.height(child.samples_world_m)
    com_uv = frame.project(child.com_world_m[None])
    com_distance = float(distance_to_polygon(parent.footprint_uv_m, com_uv)[0])
    com_scale = max(footprint_radius_m(child, frame), params.min_com_scale_m)
    best: SupportEdge | None = None
    for plane in parent.support_planes:
        over = contains(plane.polygon_uv_m, uv, tol=1e-9)
        if not np.any(over):
            continue
        gap = float(h[over].min() - plane.height_m)
        H, d_gap, d_com = _likelihood(gap, com_distance, com_scale, params)
        cand = _candidate(child.id, parent.id, H, d_gap, d_com, gap, com_distance,
                                plane.height_m)
        if best is None or (cand.likelihood, -abs(cand.gap_m)) > (best.likelihood, -abs(best.gap_m)):
            best = cand
    return best


def table_candidate(child: ObjectNode, shadowing: list[ObjectNode], frame: GravityFrame,
                    plane_point: np.ndarray, plane_normal: np.ndarray,
                    params: SupportParams) -> SupportEdge:
    """The support plane as a parent (see the module docstring)."""
    n = np.asarray(plane_normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    h = (child.samples_world_m - np.asarray(plane_point, dtype=np.float64)) @ n
    free = np.ones(len(h), dtype=bool)
    uv = frame.project(child.samples_world_m)
    for other in shadowing:
        free &= ~contains(other.footprint_uv_m, uv, tol=1e-9)
    if np.any(free):
        gap = float(h[free].min())
        H, d_gap, d_com = _likelihood(gap, 0.0, 1.0, params)
    else:
        gap = float(h.min())
        H, d_gap, d_com = 0.0, 1.0, 0.0
    return _candidate(child.id, TABLE_ID, H, d_gap, d_com, gap, 0.0, 0.0)


def support_candidates(nodes: list[ObjectNode], frame: GravityFrame, plane_point: np.ndarray,
                       plane_normal: np.ndarray, params: SupportParams
                       ) -> dict[int, list[SupportEdge]]:
    """Every child's scored candidates (table included), best first."""
    out: dict[int, list[SupportEdge]] = {}
    for child in nodes:
        below = [p for p in nodes
                 if is_broad_phase_candidate(child, p, params.footprint_overlap_tol_m)]
        cands = [table_candidate(child, below, frame, plane_point, plane_normal, params)]
        for parent in below:
            cand = object_candidate(child, parent, frame, params)
            if cand is not None:
                cands.append(cand)
        cands.sort(key=lambda c: (-c.likelihood, abs(c.gap_m), c.parent))
        out[child.id] = cands
    return out


def choose_supports(candidates: dict[int, list[SupportEdge]], params: SupportParams
                    ) -> tuple[dict[int, int], list[SupportEdge]]:
    """Tree parent per child (the max-H candidate) and the support edges to record.

    Recorded: the tree edge, plus every other candidate with H >= min_support_likelihood
    and |gap| <= max_support_gap_m (a second block under a plate, a box leaned against).

    Returns
    -------
    parent : child id -> parent id (0 = table).
    edges : the recorded edges, ``in_tree`` set on the tree's.
    """
    parent: dict[int, int] = {}
    edges: list[SupportEdge] = []
    for child, cands in candidates.items():
        best = cands[0]
        parent[child] = best.parent
        edges.append(best.model_copy(update={"in_tree": True}))
        for c in cands[1:]:
            if c.likelihood >= params.min_support_likelihood and abs(c.gap_m) <= params.max_support_gap_m:
                edges.append(c)
    return parent, edges
