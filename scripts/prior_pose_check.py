#!/usr/bin/env python
"""Is a registered prior's low silhouette IoU its pose or its shape? (synthetic scenes)

A synthetic prior is stored in its gt object's frame, so the gt pose is the pose the
prior was made for. For each scene (a copy: init/ is rewritten, and a sibling
``SCENE_exactpose`` is made) this prints, per object with a prior, the view scores that
init records for the prior (silhouette IoU with the others z-buffered, UCD mm, free space;
r2s/geometry/prior_choice.py) and its CD against gt (mm), for

* ``registered``: init as run (``--set prior_choice=prior``), from the given coarse pose;
* ``at gt pose``: the prior placed at the gt pose, scale 1, no registration;
* ``from gt pose``: init run with the gt pose given as ``world_from_prior`` (registration
  started at the answer).

If ``from gt pose`` scores much better than ``registered``, registration stops in a local
minimum; if both are alike and ``at gt pose`` is no better, the prior's shape is what the
view disagrees with.

Usage:
  python scripts/prior_pose_check.py SCENE [SCENE ...]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.geometry.prior_choice import score_in_view  # noqa: E402
from r2s.io.input_scene import load_input  # noqa: E402
from r2s.io.mesh_io import load_mesh  # noqa: E402
from r2s.io.paths import ScenePaths  # noqa: E402
from r2s.io.scene_json import read_gt_scene  # noqa: E402
from r2s.io.state import read_state  # noqa: E402
from r2s.metrics.geometry import chamfer_distance_mm, posed  # noqa: E402
from r2s.scene_model import corrected_input  # noqa: E402
from r2s.io.manifest import load_manifest  # noqa: E402


def _run_init(root: Path) -> None:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    subprocess.run([sys.executable, "-m", "r2s.cli", "init", str(root), "--set",
                    "prior_choice=prior"], check=True, env=env, capture_output=True)


def _exact_copy(root: Path) -> Path:
    """A copy of ``root``'s input/ and gt/ whose priors are given at their gt pose."""
    copy = root.parent / f"{root.name}_exactpose"
    shutil.rmtree(copy, ignore_errors=True)
    shutil.copytree(root / "input", copy / "input")
    shutil.copytree(root / "gt", copy / "gt")
    gt = {g.id: g for g in read_gt_scene(ScenePaths(root).gt_scene).objects}
    objects = json.loads((copy / "input" / "objects.json").read_text())
    for o in objects["objects"]:
        if o.get("prior_mesh") and o["id"] in gt:
            o["world_from_prior"] = np.asarray(gt[o["id"]].world_from_object).tolist()
    (copy / "input" / "objects.json").write_text(json.dumps(objects))
    return copy


def _rows(root: Path) -> dict[int, dict[str, tuple]]:
    """id -> case -> (prior score, CD mm) for the scene's init as it stands."""
    paths = ScenePaths(root)
    gt = {g.id: g for g in read_gt_scene(paths.gt_scene).objects}
    state = read_state(paths.stage_dir("init"))
    view = corrected_input(load_input(root), load_manifest(paths.manifest).model)
    specs = {s.id: s for s in view.objects}
    meshes = {o.id: posed(load_mesh(paths.stage_dir("init") / o.mesh), np.asarray(o.pose))
              for o in state.objects}
    out: dict[int, dict[str, tuple]] = {}
    for o in state.objects:
        record = getattr(o, "prior_choice", None)
        if record is None or record.get("prior") is None or o.id not in gt:
            continue
        truth = posed(load_mesh(paths.gt / gt[o.id].mesh), np.asarray(gt[o.id].world_from_object))
        at_gt = posed(load_mesh(specs[o.id].prior_mesh), np.asarray(gt[o.id].world_from_object))
        others = [(j, m) for j, m in meshes.items() if j != o.id]
        pts = np.load(paths.stage_dir("init") / o.observed_points)
        cam = view.camera
        s = score_in_view(at_gt, o.id, others, pts, cam.K, cam.world_from_camera, view.depth_m,
                          view.masks)
        out[o.id] = {"registered": (record["prior"], chamfer_distance_mm(meshes[o.id], truth)),
                     "at gt pose": (s.as_dict(), chamfer_distance_mm(at_gt, truth))}
    return out


def _fmt(score: dict, cd: float) -> str:
    return f"{score['iou']:.2f} / {score['ucd_mm']:.1f} / {score['free_space']:.3f} / {cd:.1f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="+", type=Path)
    args = parser.parse_args()
    print("| scene | id | registered IoU / UCD / free / CD | at gt pose | from gt pose |")
    print("|---|---:|---|---|---|")
    for root in args.scenes:
        _run_init(root)
        given = _rows(root)
        exact = _exact_copy(root)
        _run_init(exact)
        started = _rows(exact)
        for i in sorted(given):
            print(f"| {root.name} | {i} | {_fmt(*given[i]['registered'])} "
                  f"| {_fmt(*given[i]['at gt pose'])} | {_fmt(*started[i]['registered'])} |",
                  flush=True)


if __name__ == "__main__":
    main()
