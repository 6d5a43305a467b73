"""``r2s declutter SCENE``: an order for removing the objects one by one (a grasping
order), children before parents, in which every removal, simulated, leaves the rest at
rest.

Candidates at each step are the objects nothing else rests on (contact graph, else
height); of those the one whose removal disturbs the rest least in a 1 s PyBullet rollout
is taken. Where ``gt/`` exists the same order is replayed on the ground truth exported as
is, and the share of removals that leave the truth at rest is reported. Output:
``<scene>/declutter/plan.json``.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Optional

import numpy as np
import pybullet as pb

from r2s.errors import StageError
from r2s.io.atomic import atomic_write_json, commit_dir, recover_dir, scratch_dir
from r2s.io.paths import ScenePaths
from r2s.io.scene_lock import scene_lock
from r2s.metrics.stability import rotation_angle_deg
from r2s.physopt.hierarchy import parents_from_graph
from r2s.sim.export_scene import export_ground_truth
from r2s.sim.pybullet_bodies import body_world_from_object, connect_direct
from r2s.sim.pybullet_scene import load_export_scene

SETTLE_S = 1.0
AT_REST_M = 0.01
AT_REST_DEG = 5.0


def _poses(client: int, loaded, ids) -> dict[int, np.ndarray]:
    return {i: body_world_from_object(client, loaded.body_ids[i], loaded.com_in_object[i])
            for i in ids}


def _disturbance(client: int, loaded, remaining: list[int]) -> tuple[float, float]:
    """Largest translation (m) and rotation (deg) of ``remaining`` over SETTLE_S."""
    start = _poses(client, loaded, remaining)
    for _ in range(int(SETTLE_S * 240)):
        pb.stepSimulation(physicsClientId=client)
    end = _poses(client, loaded, remaining)
    if not remaining:
        return 0.0, 0.0
    t = max(float(np.linalg.norm(end[i][:3, 3] - start[i][:3, 3])) for i in remaining)
    r = max(float(rotation_angle_deg(start[i][:3, :3], end[i][:3, :3])) for i in remaining)
    return t, r


def _removal_effect(export_dir: Path, removed: list[int], candidate: int) -> tuple[float, float]:
    """Disturbance of removing ``candidate`` after ``removed`` (a fresh world each time)."""
    client = connect_direct()
    try:
        loaded = load_export_scene(client, export_dir)
        for i in removed + [candidate]:
            pb.removeBody(loaded.body_ids[i], physicsClientId=client)
        remaining = [i for i in loaded.ids if i not in removed and i != candidate]
        return _disturbance(client, loaded, remaining)
    finally:
        pb.disconnect(physicsClientId=client)


def _leaves(remaining: list[int], parents: Optional[dict[int, int]], heights: dict[int, float]
            ) -> list[int]:
    if parents:
        supporting = {parents.get(i) for i in remaining}
        leaves = [i for i in remaining if i not in supporting]
        if leaves:
            return sorted(leaves, key=lambda i: -heights[i])
    return sorted(remaining, key=lambda i: -heights[i])


def plan_order(export_dir: Path, parents: Optional[dict[int, int]]) -> list[dict]:
    """Greedy removal plan: [{"id", "translation_m", "rotation_deg", "at_rest"}, ...]."""
    client = connect_direct()
    try:
        loaded = load_export_scene(client, export_dir)
        ids = list(loaded.ids)
        heights = {i: float(p[2, 3]) for i, p in zip(ids, loaded.initial_world_from_object())}
    finally:
        pb.disconnect(physicsClientId=client)
    removed: list[int] = []
    steps = []
    while len(removed) < len(ids):
        remaining = [i for i in ids if i not in removed]
        best = None
        for cand in _leaves(remaining, parents, heights):
            t, r = _removal_effect(export_dir, removed, cand)
            if best is None or t < best[1]:
                best = (cand, t, r)
            if t < AT_REST_M and r < AT_REST_DEG:
                break  # leaves come highest first: the first quiet one is taken
        cand, t, r = best
        steps.append({"id": int(cand), "translation_m": t, "rotation_deg": r,
                      "at_rest": bool(t < AT_REST_M and r < AT_REST_DEG)})
        removed.append(cand)
    return steps


def replay_order(export_dir: Path, order: list[int]) -> list[dict]:
    """The same removals on another export (e.g. the ground truth)."""
    steps, removed = [], []
    for oid in order:
        t, r = _removal_effect(export_dir, removed, oid)
        steps.append({"id": int(oid), "translation_m": t, "rotation_deg": r,
                      "at_rest": bool(t < AT_REST_M and r < AT_REST_DEG)})
        removed.append(oid)
    return steps


def declutter(scene_dir: Path) -> dict:
    """Plan and simulate the removal order; holds the scene's write lock while it writes."""
    with scene_lock(Path(scene_dir)):
        return _declutter(scene_dir)


def _declutter(scene_dir: Path) -> dict:
    paths = ScenePaths(Path(scene_dir))
    if not paths.export_scene.is_file():
        raise StageError(f"{paths.export_scene} is missing; run 'r2s export' first")
    parents = parents_from_graph(paths.contact_graph)
    plan = plan_order(paths.export, parents)
    report: dict = {"order": [s["id"] for s in plan], "steps": plan,
                    "success_rate": float(np.mean([s["at_rest"] for s in plan]))}
    if paths.gt_scene.is_file():
        with tempfile.TemporaryDirectory(prefix="r2s-declutter-") as work:
            gt_steps = replay_order(export_ground_truth(paths.root, Path(work)), report["order"])
        report["ground_truth"] = {"steps": gt_steps,
                                  "success_rate": float(np.mean([s["at_rest"] for s in gt_steps]))}
    out = paths.stage_dir("declutter")
    recover_dir(out)
    tmp = scratch_dir(out)
    atomic_write_json(tmp / "plan.json", report)
    commit_dir(tmp, out)
    return report
