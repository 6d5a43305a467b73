#!/usr/bin/env python
"""What the ground truth itself scores on evaluate's observation measures.

The observation metrics (silhouette IoU against the input masks, UCD of the masked depth
points, free-space violation; r2s/metrics/observation.py) compare a twin with the view,
and the view has its own errors: a mask that bleeds onto the table or a shadow, one object
split into two ids, a sliver, depth noise. This script scores each scene's gt objects (the
meshes of ``gt/scene.json`` at their poses) against the scene's ``input/`` with the same
function evaluate calls, so a table of r2s's figures can be read beside what an exact
reconstruction would get: where the ground truth scores an IoU under a target, meeting
the target means fitting the masks' errors.

Prints one row per scene and one pooled the way ``scripts/bench_realistic.py`` pools (IoU:
the mean of the scenes' pooled IoUs; UCD, UCD above the table and free space: means over
objects; min IoU: the worst object whose mask has >= 1000 px, instances with no gt object
counting 0 as in evaluate).

Usage:
  python scripts/observation_ceiling.py bench/fresh9/scene_0*_prior
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Optional

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.io.input_scene import load_input  # noqa: E402
from r2s.io.mesh_io import load_mesh  # noqa: E402
from r2s.io.scene_json import read_gt_scene  # noqa: E402
from r2s.io.state import read_state  # noqa: E402
from r2s.metrics.observation import instance_ids, observe_scene  # noqa: E402
from r2s.scene_model import corrected_input  # noqa: E402


def gt_observation(scene: Path) -> dict:
    """evaluate's observation figures of ``scene``'s gt objects against its input view
    (as evaluate reads it: the ids of a split mask or a sliver merged into their object):
    ``iou`` (pooled), ``min_iou`` (worst object of >= 1000 mask px, None if none), and per
    object lists ``ucd_mm``, ``ucd_above_mm`` (points above the support plane init fitted,
    when init has run; else above z = 0) and ``free_space``."""
    loaded = load_input(scene)
    view = corrected_input(loaded, None)  # evaluate's view: fragments of a mask merged
    if not np.allclose(view.camera.world_from_camera, loaded.camera.world_from_camera):
        raise SystemExit(f"{scene}: r2s levelled this scene's world; its gt frame no longer "
                         "matches the view")
    gt = read_gt_scene(scene / "gt" / "scene.json")
    meshes = [load_mesh(scene / "gt" / o.mesh).apply_transform(np.asarray(o.world_from_object))
              for o in gt.objects]
    support = (np.zeros(3), np.array([0.0, 0.0, 1.0]))
    if (scene / "init" / "state.json").is_file():
        plane = read_state(scene / "init").support
        support = (np.asarray(plane.point, dtype=float), np.asarray(plane.normal, dtype=float))
    observed = observe_scene(meshes, [o.id for o in gt.objects], view.camera.K,
                             view.camera.world_from_camera, view.depth_m, view.masks,
                             mask_ids=instance_ids(view.masks), support=support)
    summary = observed.summary()
    present = [o for o in observed.objects if not o.missing]
    return {"iou": summary["silhouette_iou"], "min_iou": summary["min_silhouette_iou"],
            "per_object_iou": {o.id: o.iou for o in observed.objects},
            "ucd_mm": [o.ucd_mm for o in present],
            "ucd_above_mm": [o.ucd_above_support_mm for o in present],
            "free_space": [o.free_space_violation for o in present]}


def _mean(values) -> Optional[float]:
    vals = [float(v) for v in values if v is not None]
    return sum(vals) / len(vals) if vals else None


def _fmt(value: Optional[float], digits: int) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def _row(name: str, figures: list[dict]) -> str:
    pooled = lambda key: _mean([v for f in figures for v in f[key]])  # noqa: E731
    mins = [f["min_iou"] for f in figures if f["min_iou"] is not None]
    return (f"| {name} | {_fmt(_mean([f['iou'] for f in figures]), 3)} | "
            f"{_fmt(min(mins) if mins else None, 2)} | {_fmt(pooled('ucd_mm'), 1)} | "
            f"{_fmt(pooled('ucd_above_mm'), 1)} | {_fmt(pooled('free_space'), 3)} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="+", type=Path)
    ap.add_argument("--objects", action="store_true",
                    help="also print each scene's per-object IoU (id:IoU; 0 for an instance "
                         "with no gt object)")
    args = ap.parse_args()
    scenes = [s for s in args.scenes if (s / "gt" / "scene.json").is_file()
              and (s / "input").is_dir()]
    if not scenes:
        raise SystemExit("no scene with input/ and gt/scene.json among the arguments")
    print("| scene (ground truth) | silhouette IoU | min IoU (>= 1000 px) | UCD [mm] | "
          "UCD above the table [mm] | free-space violation |")
    print("|---|---:|---:|---:|---:|---:|")
    figures = []
    for scene in scenes:
        figures.append(gt_observation(scene))
        print(_row(f"{scene.parent.name}/{scene.name}", [figures[-1]]), flush=True)
        if args.objects:
            print("  " + " ".join(f"{i}:{_fmt(v or 0.0, 2)}"
                                  for i, v in figures[-1]["per_object_iou"].items()))
    print(_row(f"pooled ({len(scenes)} scenes)", figures))


if __name__ == "__main__":
    main()
