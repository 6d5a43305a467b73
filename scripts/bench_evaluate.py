#!/usr/bin/env python
"""Benchmark of the evaluate stage: wall time per part and the metrics it reports.

Scenes (built in a temporary folder, nothing in the repository is written):
  synth6  six primitives (boxes, cylinders, a sphere) written straight into export/ + gt/;
          one cylinder is released 7 cm up, one box floats 3 mm.
  ycb5    ../shared/seed_demo/ycb5 (7 YCB objects, 16k faces each) exported from its gt
          by the export stage (source=gt, CoACD pieces), if the folder exists.

Usage:
  python scripts/bench_evaluate.py [--samples 10000] [--repeat 1]
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.io.export_writer import ExportBody, write_export  # noqa: E402
from r2s.runner.base import run_stage  # noqa: E402
from r2s.stages.evaluate import SCENE_KEYS, STAGE, Options  # noqa: E402

SEED_DEMO = REPO.parent / "shared" / "seed_demo" / "ycb5"


def _pose(t, rot=None) -> np.ndarray:
    out = np.eye(4)
    if rot is not None:
        out[:3, :3] = rot
    out[:3, 3] = t
    return out


def synth6(root: Path) -> Path:
    """Six primitives on a plane: export == gt, one falling cylinder, one floating box."""
    box = trimesh.creation.box([0.06, 0.06, 0.06])
    cyl = trimesh.creation.cylinder(radius=0.03, height=0.08, sections=48)
    sph = trimesh.creation.icosphere(subdivisions=3, radius=0.03)
    lying = trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0])[:3, :3]
    items = [(1, "box", box, _pose([0, 0, 0.03])), (2, "box_on_box", box, _pose([0, 0, 0.0905])),
             (3, "cylinder", cyl, _pose([0.12, 0, 0.04])),
             (4, "ball", sph, _pose([-0.12, 0.05, 0.03])),
             (5, "floating_box", box, _pose([0.1, 0.12, 0.033])),
             (6, "falling_cylinder", cyl, _pose([-0.05, -0.15, 0.1], lying))]
    bodies, gt_objects = [], []
    (root / "gt" / "meshes").mkdir(parents=True)
    for obj_id, label, mesh, pose in items:
        bodies.append(ExportBody(obj_id, label, mesh, [mesh.convex_hull], pose, 0.2,
                                 np.zeros(3), np.eye(3) * 1e-4, 0.8, extra={"source": "prior"}))
        mesh.export(root / "gt" / "meshes" / f"{obj_id}.glb")
        gt_objects.append({"id": obj_id, "label": label, "mesh": f"meshes/{obj_id}.glb",
                           "world_from_object": pose.tolist(), "mass_kg": 0.2, "friction": 0.8})
    support = {"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1], "friction": 0.8}
    write_export(root / "export", [0, 0, -9.81], support, bodies)
    (root / "gt" / "scene.json").write_text(json.dumps(
        {"gravity": [0, 0, -9.81], "objects": gt_objects, "support": support}))
    cam = {"width": 640, "height": 480, "K": [[554.3, 0, 319.5], [0, 554.3, 239.5], [0, 0, 1]],
           "world_from_camera": _look_at([0.5, -0.4, 0.45], [0, 0, 0.03]).tolist()}
    (root / "input").mkdir()
    (root / "input" / "camera.json").write_text(json.dumps(cam))
    return root


def _look_at(eye, target) -> np.ndarray:
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    return _pose(eye, np.stack([x, np.cross(z, x), z], axis=1))


def ycb5(root: Path) -> Path | None:
    if not SEED_DEMO.is_dir():
        return None
    shutil.copytree(SEED_DEMO, root)
    from r2s.runner.registry import get_stage

    export = get_stage("export")
    t0 = time.perf_counter()
    run_stage(export, root, export.options_type(source="gt"))
    print(f"  (export of ycb5 from gt: {time.perf_counter() - t0:.1f} s)")
    return root


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--samples", type=int, default=10000, help="geometry_samples")
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args()
    options = Options(geometry_samples=args.samples)
    with tempfile.TemporaryDirectory() as tmp:
        scenes = {"synth6": synth6(Path(tmp) / "synth6"), "ycb5": ycb5(Path(tmp) / "ycb5")}
        for name, scene in scenes.items():
            if scene is None:
                print(f"{name}: skipped ({SEED_DEMO} not found)")
                continue
            times = []
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                res = run_stage(STAGE, scene, options)
                times.append(time.perf_counter() - t0)
            metrics = json.loads((scene / "evaluate" / "metrics.json").read_text())
            n = len(metrics["objects"])
            print(f"{name}: {n} objects, evaluate {min(times):.2f} s (best of {args.repeat})")
            for key in SCENE_KEYS:
                v = res.summary[key]
                print(f"  {key:26s} {v:.4g}" if isinstance(v, float) else f"  {key:26s} {v}")
            for o in metrics["objects"]:
                cd = None if o["chamfer_mm"] is None else round(o["chamfer_mm"], 3)
                iou = None if o["iou"] is None else round(o["iou"], 3)
                print(f"  id {o['id']:2d} {o['label'][:16]:16s} stable={o['stable']!s:5s} "
                      f"drift {1000 * o['translation_drift_m']:7.1f} mm "
                      f"{o['rotation_drift_deg']:6.1f} deg pen {o['penetration_mm']:5.1f} mm "
                      f"gap {o['gap_mm']:5.1f} mm CD {cd} IoU {iou}")


if __name__ == "__main__":
    main()
