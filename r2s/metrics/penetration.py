"""Interpenetration and floating of the loaded (not yet simulated) scene, via PyBullet.

Signed distances come from ``pybullet.getClosestPoints`` between every pair of bodies,
support plane included. PyBullet inflates every convex mesh piece by a collision margin of
:data:`PYBULLET_MESH_MARGIN_M` (the plane gets none) and reports distances between the
inflated shapes; :func:`scene_distances` adds the margins back, so the numbers are about
the exported geometry itself (two boxes overlapping by 5 mm read 5 mm, not 7 mm).

Distances are signed: negative = penetration depth, positive = gap.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as pb

from r2s.sim.pybullet_scene import LoadedScene

PYBULLET_MESH_MARGIN_M = 0.001
"""Collision margin PyBullet gives a ``GEOM_MESH`` convex piece (checked by the tests)."""

CONTACT_TOLERANCE_M = 1e-6
"""|signed distance| below this counts as touching (PyBullet computes in float32)."""

SUPPORT_ID = 0
"""Id used for the support plane in pair lists (object ids are positive)."""


@dataclass(frozen=True)
class SceneDistances:
    """Signed minimum distances between the bodies of a scene, metres.

    Attributes
    ----------
    ids : (N,) int object ids.
    object_object_m : (N, N) float, symmetric; ``inf`` on the diagonal and for pairs
        farther apart than the search radius.
    object_support_m : (N,) float distance of each object to the support plane.
    """

    ids: np.ndarray
    object_object_m: np.ndarray
    object_support_m: np.ndarray


def _min_distance_m(client: int, body_a: int, body_b: int, search_m: float) -> float:
    points = pb.getClosestPoints(body_a, body_b, search_m, physicsClientId=client)
    if not points:
        return float("inf")
    return float(min(p[8] for p in points))


def scene_distances(client: int, loaded: LoadedScene, search_m: float = 1.0) -> SceneDistances:
    """Margin-corrected signed distances between all bodies in their current poses."""
    ids = loaded.ids
    n = len(ids)
    pair = np.full((n, n), np.inf)
    support = np.full(n, np.inf)
    for i, id_a in enumerate(ids):
        body_a = loaded.body_ids[id_a]
        d = _min_distance_m(client, body_a, loaded.support_body, search_m)
        support[i] = d + PYBULLET_MESH_MARGIN_M
        for j in range(i + 1, n):
            d = _min_distance_m(client, body_a, loaded.body_ids[ids[j]],
                                search_m + 2 * PYBULLET_MESH_MARGIN_M)
            pair[i, j] = pair[j, i] = d + 2 * PYBULLET_MESH_MARGIN_M
    return SceneDistances(ids=np.asarray(ids, dtype=np.int64), object_object_m=pair,
                          object_support_m=support)


@dataclass(frozen=True)
class PenetrationMetrics:
    """Penetration / floating summary (millimetres; depths are positive numbers).

    Attributes
    ----------
    max_penetration_mm : deepest overlap between any two bodies, support plane included;
        0 when nothing overlaps.
    mean_penetration_mm : mean depth over the overlapping pairs (support included); 0 if none.
    object_max_penetration_mm, object_mean_penetration_mm : the same over object-object
        pairs only.
    penetrating_pairs : list of (id_a, id_b, depth_mm), id 0 = support plane, deepest first.
    per_object_penetration_mm : (N,) deepest overlap of each object with anything.
    per_object_gap_mm : (N,) distance to the nearest other body or the plane, 0 when
        touching or overlapping, ``inf`` when nothing is within the search radius.
    floating : (N,) bool, ``per_object_gap_mm > floating_gap_mm``.
    floating_objects : number of floating objects.
    """

    max_penetration_mm: float
    mean_penetration_mm: float
    object_max_penetration_mm: float
    object_mean_penetration_mm: float
    penetrating_pairs: list
    per_object_penetration_mm: np.ndarray
    per_object_gap_mm: np.ndarray
    floating: np.ndarray
    floating_objects: int


def penetration_metrics(dist: SceneDistances, floating_gap_mm: float = 2.0,
                        tolerance_m: float = CONTACT_TOLERANCE_M) -> PenetrationMetrics:
    """Summarise :class:`SceneDistances` (pure function).

    Signed distances within ``tolerance_m`` of zero are read as exact contact.
    """
    ids = [int(i) for i in dist.ids]
    def snap(d: np.ndarray) -> np.ndarray:
        return np.where(np.abs(d) < tolerance_m, 0.0, d)

    dist = SceneDistances(ids=dist.ids, object_object_m=snap(dist.object_object_m),
                          object_support_m=snap(dist.object_support_m))
    n = len(ids)
    pairs: list[tuple[int, int, float]] = []
    object_depths: list[float] = []
    for i in range(n):
        if dist.object_support_m[i] < 0:
            pairs.append((ids[i], SUPPORT_ID, -1000.0 * float(dist.object_support_m[i])))
        for j in range(i + 1, n):
            if dist.object_object_m[i, j] < 0:
                depth = -1000.0 * float(dist.object_object_m[i, j])
                pairs.append((ids[i], ids[j], depth))
                object_depths.append(depth)
    pairs.sort(key=lambda p: -p[2])
    depths = [p[2] for p in pairs]

    nearest = np.minimum(dist.object_object_m.min(axis=1) if n else np.zeros(0),
                         dist.object_support_m)
    per_object_pen = np.where(nearest < 0, -1000.0 * nearest, 0.0)
    gap = np.where(nearest > 0, 1000.0 * nearest, 0.0)
    floating = gap > floating_gap_mm
    return PenetrationMetrics(
        max_penetration_mm=max(depths, default=0.0),
        mean_penetration_mm=float(np.mean(depths)) if depths else 0.0,
        object_max_penetration_mm=max(object_depths, default=0.0),
        object_mean_penetration_mm=float(np.mean(object_depths)) if object_depths else 0.0,
        penetrating_pairs=[list(p) for p in pairs],
        per_object_penetration_mm=per_object_pen,
        per_object_gap_mm=gap,
        floating=floating,
        floating_objects=int(floating.sum()),
    )
