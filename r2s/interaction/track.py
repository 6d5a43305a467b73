"""Object motion between the images before and after an interaction: a small tracker.

Where ``input/interaction/`` holds the depth and masks seen after a push but no measured
displacements (``observed.json``), each object's motion is measured from the images: its
reconstructed mesh, at its reconstructed pose (fitted to the image before), is registered
rigidly (no scale) to the points seen after, starting from that pose shifted by the shift
of the centroid of the object's observed points. The centre-of-mass displacement follows
from the two poses. An object whose registration explains too few of its points after
the push (hidden, or moved out of view) is left out: it was not observed.

All frames are the world frame of ``input/camera.json``; lengths are metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from r2s.geometry.registration import IcpOptions, register_prior

TRACK_ICP = IcpOptions(estimate_scale=False, max_correspondence_m=(0.03, 0.015, 0.008, 0.004),
                       local_yaw_steps=8, global_fallback_fitness=0.0, model_samples=8000,
                       max_observed_points=2000, edge_weight=0.0)
"""Rigid ICP from the shifted pose, with turned starts about the table normal (a pushed
object may turn) but no global search."""


@dataclass(frozen=True)
class TrackedObject:
    """One object's measured motion.

    world_from_object_after : (4, 4) its pose after the interaction.
    displacement_m : (3,) centre-of-mass displacement, world frame.
    fitness : share of its points after within 5 mm of the registered mesh.
    rmse_m : RMS distance of those points.
    """

    id: int
    world_from_object_after: np.ndarray
    displacement_m: np.ndarray
    fitness: float
    rmse_m: float


def track_objects(meshes: dict[int, trimesh.Trimesh], world_from_object: dict[int, np.ndarray],
                  com_in_object: dict[int, np.ndarray], points_before: dict[int, np.ndarray],
                  points_after: dict[int, np.ndarray], viewpoint: np.ndarray, up: np.ndarray,
                  min_points: int = 50, min_fitness: float = 0.5,
                  options: IcpOptions = TRACK_ICP) -> dict[int, TrackedObject]:
    """Motion of every object seen in both images.

    Parameters
    ----------
    meshes : id -> the object's mesh in its own frame (the reconstruction's, scaled).
    world_from_object : id -> (4, 4) its pose before (the reconstruction's).
    com_in_object : id -> (3,) its centre of mass, object frame.
    points_before, points_after : id -> (N, 3) world points of the instance in the image
        before / after.
    viewpoint : (3,) camera centre, world; up : (3,) table normal.
    min_points : fewer points in either image: not tracked.
    min_fitness : a registration explaining fewer of the points after: dropped.

    Returns
    -------
    id -> :class:`TrackedObject`, for the objects tracked.
    """
    out: dict[int, TrackedObject] = {}
    for oid, mesh in meshes.items():
        before, after = points_before.get(oid), points_after.get(oid)
        if before is None or after is None or min(len(before), len(after)) < min_points:
            continue
        pose = np.asarray(world_from_object[oid], dtype=np.float64)
        start = pose.copy()
        start[:3, 3] += after.mean(axis=0) - before.mean(axis=0)
        # the unshifted pose too: an object that did not move keeps its centroid only
        # up to what occlusion changed
        best = None
        for init in (start, pose):
            res = register_prior(mesh, after, world_from_prior=init, viewpoint=viewpoint,
                                 up=up, options=options)
            if best is None or (res.fitness, -res.rmse_m) > (best.fitness, -best.rmse_m):
                best = res
        if best is None or best.fitness < min_fitness:
            continue
        com = np.asarray(com_in_object[oid], dtype=np.float64)
        moved = (best.world_from_object[:3, :3] @ com + best.world_from_object[:3, 3]) - (
            pose[:3, :3] @ com + pose[:3, 3])
        out[oid] = TrackedObject(oid, best.world_from_object, moved, float(best.fitness),
                                 float(best.rmse_m))
    return out
