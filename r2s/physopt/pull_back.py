"""After physopt's repairs: bring the objects they moved back to where the solve started, as
far as the scene still rests.

The differentiable pass and the repair rounds (:mod:`r2s.physopt.repair`) move objects
until nothing moves in the check; the COM and friction they tuned on the way change
nothing the camera sees, but the poses do, and a few millimetres and degrees cost an
object of 60 pixels a tenth of its silhouette IoU. The solve starts from the poses it was
given (geomopt's, else init's: where the objects were seen) with their collision pieces
separated (depenetration; that move is physical and stays). Once the repaired scene
rests, a few candidate states that keep the tuned COM, mass and friction and put poses
back towards those start poses are checked in the judge's worlds, in order of least
observation change:

1. ``all``: every moved object back at its start pose;
2. ``all but movers``: the objects that moved in the check of 1 keep their repaired
   poses, the rest go back; when something still moves, its objects are left out too
   (``MAX_EXCLUSIONS`` times at most);
3. ``halfway``: every moved object halfway back (position of its centre and rotation
   interpolated).

At most ``MAX_EXCLUSIONS + 2`` checks. The first candidate in which nothing moves (the same at-rest tolerance the repairs
answer to) is kept; when none rests, the repaired state stands.

Frames: poses are (4, 4) ``world_from_object``; ``centres`` (3,) each mesh's centroid in
its object frame, the point whose motion counts (as in
:mod:`r2s.physopt.observation_bound`).
"""

from __future__ import annotations

from typing import Mapping, Optional

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from r2s.metrics.observation import pose_displacement
from r2s.physopt.params import Drift, Params
from r2s.physopt.repair import MakeWorld, check, judge_orders

MOVED_M = 5e-4
"""An object whose centre is farther than this from its start pose (metres), ..."""
MOVED_DEG = 0.5
"""... or that is turned more than this (degrees), was moved by physopt."""
MAX_EXCLUSIONS = 2
"""How many times the objects that moved in a candidate's check are left out (keep their
repaired poses) and the rest tried again."""


def interpolated_pose(target: np.ndarray, current: np.ndarray, centre_in_object: np.ndarray,
                      towards_target: float) -> np.ndarray:
    """(4, 4) pose a fraction ``towards_target`` of the way from ``current`` back to
    ``target`` (0: current, 1: target): the object-frame point ``centre_in_object`` (3,)
    moves on the straight line, the rotation on the shortest arc."""
    target = np.asarray(target, dtype=np.float64)
    current = np.asarray(current, dtype=np.float64)
    c = np.asarray(centre_in_object, dtype=np.float64)
    rots = Rotation.from_matrix(np.stack([current[:3, :3], target[:3, :3]]))
    rot = Slerp([0.0, 1.0], rots)([float(towards_target)]).as_matrix()[0]
    here = current[:3, :3] @ c + current[:3, 3]
    there = target[:3, :3] @ c + target[:3, 3]
    centre = here + float(towards_target) * (there - here)
    out = np.eye(4)
    out[:3, :3] = rot
    out[:3, 3] = centre - rot @ c
    return out


def moved_objects(params: Params, start: Mapping[int, np.ndarray],
                  centres: Mapping[int, np.ndarray]) -> list[int]:
    """Movable ids whose pose is more than ``MOVED_M`` / ``MOVED_DEG`` from their
    ``start`` pose (ids without one are left out)."""
    out = []
    for i, p in params.items():
        if i not in start or not p.movable:
            continue
        m, deg = pose_displacement(start[i], p.world_from_object, centres[i])
        if m > MOVED_M or deg > MOVED_DEG:
            out.append(i)
    return sorted(out)


def pull_back(make_world: MakeWorld, params: Params, drift: Drift,
              start: Mapping[int, np.ndarray], centres: Mapping[int, np.ndarray],
              export_order: list[int], settings, log: dict) -> tuple[Params, Drift]:
    """The repaired state (``params`` and its check ``drift``) with poses put back
    towards ``start`` (id -> (4, 4), the solve's poses after depenetration) where the
    scene still rests (module docstring);
    ``settings``: the repair settings (``moving``, ``verify_duration_s``). ``log``
    (physopt/log.json's record) gets a ``pull_back`` entry and a line per object moved
    back."""
    moved = moved_objects(params, start, centres)
    record: dict = {"moved": moved, "tried": [], "kept": None}
    log["pull_back"] = record
    if not moved or settings.moving(drift):
        return params, drift
    orders = judge_orders(export_order)

    def attempt(name: str, ids: list[int], towards_start: float
                ) -> tuple[list[int], Optional[tuple[Params, Drift]]]:
        """Check one candidate: (its movers, and the state with its check when it rests,
        else None); a resting candidate's objects get their log lines."""
        trial = {**params, **{i: params[i].with_pose(interpolated_pose(
            start[i], params[i].world_from_object, centres[i], towards_start)) for i in ids}}
        result = check(make_world, trial, orders, settings.verify_duration_s)
        movers = settings.moving(result)
        record["tried"].append({"candidate": name, "ids": ids, "fraction": towards_start,
                                "moving": movers})
        if movers:
            return movers, None
        record["kept"] = name
        for i in ids:
            before = pose_displacement(start[i], params[i].world_from_object, centres[i])
            after = pose_displacement(start[i], trial[i].world_from_object, centres[i])
            log["objects"][i].append(
                f"pulled back towards its start pose ({name}): "
                f"{before[0] * 1000:.1f} mm, {before[1]:.1f} deg -> "
                f"{after[0] * 1000:.1f} mm, {after[1]:.1f} deg")
        return movers, (trial, result)

    ids = moved
    movers, kept = attempt("all", ids, 1.0)
    left_out: set[int] = set()
    for _ in range(MAX_EXCLUSIONS):
        if kept is not None:
            break
        left_out |= set(movers)
        rest = [i for i in moved if i not in left_out]
        if not rest or rest == ids:
            break
        ids = rest
        movers, kept = attempt("all but movers", ids, 1.0)
    if kept is None:
        movers, kept = attempt("halfway", moved, 0.5)
    return kept if kept is not None else (params, drift)
