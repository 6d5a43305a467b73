"""Completion without priors, before and after the observation-respecting completion.

For each given synthetic scene (input/ + gt/, objects without priors), runs init in two
copies: ``before`` (no point cleanup, no carving) and ``after`` (the defaults), and prints
per object: extents error (world axis-aligned box of the completed mesh vs the truth's,
largest relative error over x, y, z), centroid error (volume centroids, mm), and the
free space the completion takes (pixels outside a 2-pixel band around the object's mask
where the rendered completion is >= 15 mm in front of a valid observed depth, divided by
the mask area). Mask ids with no ground-truth object (a realistic segmenter's split or
sliver ids) are completed but not scored. With ``--run`` the whole pipeline runs too and the stability ratio of
evaluate is printed.

Usage:
    PYTHONPATH=$PWD python scripts/bench_completion.py WORKDIR SCENE [SCENE ...] [--run]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import trimesh
from scipy import ndimage

from r2s.geometry.raycast import raycast_view
from r2s.io.input_scene import load_input
from r2s.io.mesh_io import load_mesh

VARIANTS = {
    "before": ["init.completion_clean_points=false", "init.completion_carve=false"],
    "after": [],
}


def _posed(path: Path, world_from_object) -> trimesh.Trimesh:
    mesh = load_mesh(path)
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    mesh.apply_transform(np.asarray(world_from_object, dtype=np.float64))
    return mesh


def _r2s(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "r2s.cli", *args], check=True,
                   stdout=subprocess.DEVNULL)


def measure(scene: Path) -> list[dict]:
    inp = load_input(scene)
    cam = inp.camera
    gt = json.loads((scene / "gt" / "scene.json").read_text())
    truth = {o["id"]: _posed(scene / "gt" / o["mesh"], o["world_from_object"])
             for o in gt["objects"]}
    state = json.loads((scene / "init" / "state.json").read_text())
    posed = {o["id"]: _posed(scene / "init" / o["mesh"], o["world_from_object"])
             for o in state["objects"]}
    ids = list(posed)
    depth_r, index, _ = raycast_view([posed[i] for i in ids], cam.K, cam.world_from_camera,
                                     cam.width, cam.height)
    obs = inp.depth_m
    rows = []
    for i in ids:
        if i not in truth:  # a mask id a segmenter made up (a split object, a sliver)
            continue
        mine = inp.masks == i
        band = ndimage.binary_dilation(mine, iterations=2)
        # the object alone, so an object hidden behind another still counts
        d_k, idx_k, _ = raycast_view([posed[i]], cam.K, cam.world_from_camera,
                                     cam.width, cam.height)
        with np.errstate(invalid="ignore"):
            viol = (idx_k == 0) & ~band & np.isfinite(obs) & (d_k < obs - 0.015)
        ext_m, ext_t = posed[i].extents, truth[i].extents
        rows.append({
            "id": i,
            "extents_mm": [round(1000 * float(v)) for v in ext_m],
            "truth_mm": [round(1000 * float(v)) for v in ext_t],
            "extents_err": float(np.max(np.abs(ext_m - ext_t) / ext_t)),
            "centroid_mm": 1000 * float(np.linalg.norm(posed[i].center_mass
                                                       - truth[i].center_mass)),
            "free_space": float(viol.sum()) / max(int(mine.sum()), 1),
        })
    return rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("workdir", type=Path)
    ap.add_argument("scenes", type=Path, nargs="+")
    ap.add_argument("--run", action="store_true")
    a = ap.parse_args()
    for src in a.scenes:
        for name, sets in VARIANTS.items():
            dst = a.workdir / f"{src.name}_{name}"
            if not dst.exists():
                dst.mkdir(parents=True)
                shutil.copytree(src / "input", dst / "input")
                shutil.copytree(src / "gt", dst / "gt")
            opts = [x for s in sets for x in ("--set", s)]
            _r2s("run", str(dst), "--force", *([] if a.run else ["--until", "init"]), *opts)
            rows = measure(dst)
            for r in rows:
                print(f"{src.name:8s} {name:6s} id={r['id']:2d} extents {r['extents_mm']} "
                      f"truth {r['truth_mm']} err {100 * r['extents_err']:5.1f}% "
                      f"centroid {r['centroid_mm']:6.1f} mm free-space {r['free_space']:.3f}")
            e = np.array([r["extents_err"] for r in rows])
            c = np.array([r["centroid_mm"] for r in rows])
            f = np.array([r["free_space"] for r in rows])
            line = (f"{src.name:8s} {name:6s} MEAN extents err {100 * e.mean():5.1f}% "
                    f"(max {100 * e.max():5.1f}%) centroid {c.mean():6.1f} mm "
                    f"(max {c.max():6.1f}) free-space {f.mean():.3f} (max {f.max():.3f})")
            if a.run:
                m = json.loads((dst / "evaluate" / "metrics.json").read_text())
                line += f" stability {m.get('stability_ratio')}"
            print(line, flush=True)


if __name__ == "__main__":
    main()
