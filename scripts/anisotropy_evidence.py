#!/usr/bin/env python
"""Do the priors register with one scale across the view and another along it?

An idea for diagnose's generic residual model (docs/diagnose.md section 6), measured and
not adopted: a focal length declared (1 + e) times too long shrinks every observed point
across the view (camera x, y) by 1 / (1 + e) and leaves its depth, so a metric prior
should register about e smaller across the view than along it, which no catalogued effect
predicts (a depth scale or offset is isotropic at an object, a camera rotation changes no
size). For each scene (``scripts/bench_diagnose.py``'s folders, init run) every object with
a metric prior seen by ``--min-points`` points is registered as diagnose does (isotropic,
free pose); then with one scale across the view and one along the optical axis, either
with the pose free (``free``) or from the isotropic pose with the rotation held
(``held``, translation and the two scales free). Prints per object the anisotropy
``log(scale across) - log(scale along)`` (%) and per scene its median and mean; then, per
case (the folder name without ``_s<seed>``), the range of the scene medians.

Usage:
  python scripts/anisotropy_evidence.py --variant held bench/diagnose/clean_s0 ...
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.diagnose.measure.observe import object_points_camera  # noqa: E402
from r2s.diagnose.measure.scale_fit import SurfaceModel, fit_prior_scale, free_space  # noqa: E402
from r2s.diagnose.measure.scene_dir import load_objects  # noqa: E402
from r2s.io.input_scene import load_input  # noqa: E402
from r2s.io.paths import ScenePaths  # noqa: E402
from r2s.io.state import read_state  # noqa: E402


def object_anisotropy(model: SurfaceModel, pts: np.ndarray, start: np.ndarray, view,
                      variant: str) -> tuple[float, float, float]:
    """(isotropic log scale, anisotropy, fitness of the isotropic fit) of one object."""
    iso = fit_prior_scale(model, pts, start, view=view, free_space_weight=0.5)
    if variant == "free":
        fit = fit_prior_scale(model, pts, start, view=view, free_space_weight=0.5,
                              axes="across_along")
    else:
        fit = fit_prior_scale(model, pts, iso.object_from_camera, view=view,
                              free_space_weight=0.5, axes="across_along", fit_rotation=False,
                              schedule_m=(0.005, 0.003), iterations_per_level=15)
    across, _, along = fit.log_scale_axes
    return float(np.log(iso.scale)), across - along, iso.fitness


def scene_anisotropy(scene: Path, variant: str, min_points: int, min_fitness: float) -> dict:
    paths = ScenePaths(scene)
    inp = load_input(paths.root)
    objects = load_objects(paths, "init", read_state(paths.stage_dir("init")), inp)
    rows = []
    for o in objects:
        if not o.prior_area_m2:
            continue
        pts = object_points_camera(inp, o.id)
        if len(pts) < min_points:
            continue
        view = free_space(inp.camera.K, inp.depth_m, inp.masks == o.id)
        start = np.linalg.inv(o.world_from_object) @ inp.camera.world_from_camera
        log_iso, aniso, fitness = object_anisotropy(SurfaceModel(o.mesh), pts, start, view,
                                                    variant)
        if fitness >= min_fitness:
            rows.append({"id": o.id, "label": o.label, "points": len(pts),
                         "log_scale": log_iso, "anisotropy": aniso})
    a = np.array([r["anisotropy"] for r in rows])
    return {"scene": scene.name, "objects": rows,
            "median": float(np.median(a)) if len(a) else None,
            "mean": float(np.mean(a)) if len(a) else None}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("scenes", nargs="+", type=Path)
    ap.add_argument("--variant", choices=("free", "held"), default="held")
    ap.add_argument("--min-points", type=int, default=150)
    ap.add_argument("--min-fitness", type=float, default=0.6)
    ap.add_argument("--json", type=Path, default=None, help="write the rows here")
    args = ap.parse_args()
    out = []
    for scene in args.scenes:
        r = scene_anisotropy(scene, args.variant, args.min_points, args.min_fitness)
        out.append(r)
        objs = " ".join(f"{o['label'][:12]}:{100 * o['anisotropy']:+.1f}" for o in r["objects"])
        med = "-" if r["median"] is None else f"{100 * r['median']:+.1f}"
        mean = "-" if r["mean"] is None else f"{100 * r['mean']:+.1f}"
        print(f"{r['scene']}: {objs} | median {med} % mean {mean} %", flush=True)
    print()
    for case in dict.fromkeys(r["scene"].rsplit("_s", 1)[0] for r in out):
        meds = [100 * r["median"] for r in out
                if r["scene"].rsplit("_s", 1)[0] == case and r["median"] is not None]
        if meds:
            print(f"{case}: {len(meds)} scenes, scene medians {min(meds):+.1f} .. "
                  f"{max(meds):+.1f} % (median {np.median(meds):+.1f} %)")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
