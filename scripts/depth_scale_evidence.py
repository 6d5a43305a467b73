#!/usr/bin/env python
"""Per object and per scene: how well the prior scales see an injected depth bias.

For each benchmark scene (``scripts/bench_diagnose.py``'s folders, init run), every object
with a metric prior is registered with a free scale as diagnose does, and the fitted log
scale is compared with what it should be: the injected bias's apparent size factor at the
object's depth (``s + o s / (z - o)``) divided by the prior's own size error (the geometric
mean of its per-axis scale errors, recorded in gt/: a prior 3 % large registers at 1/1.03). Prints one line per object and, per scene,
the weighted mean log scale with its standard error, the table's offset evidence and what
diagnose's depth fits say with their noise bars. With ``--true-mesh`` each object is also
registered with its true mesh (gt/) at its true pose: what the fit itself makes of a
perfect prior (its own bias), apart from the prior's size error.

Usage:
  python scripts/depth_scale_evidence.py bench/diagnose/depth_scale_s0 bench/diagnose/clean_s0
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.diagnose.effects import get_effect  # noqa: E402
from r2s.diagnose.measure.scene_dir import MeasureSettings, measure_scene  # noqa: E402
from r2s.diagnose.stats.table_offset import offset_evidence  # noqa: E402
from r2s.io.paths import ScenePaths  # noqa: E402


def injected_bias(gt: dict) -> tuple[float, float]:
    inj = gt.get("injected_effects") or {}
    s = float((inj.get("depth_scale") or {}).get("value", 1.0))
    o = float((inj.get("depth_offset_m") or {}).get("value", 0.0))
    return s, o


def true_mesh_scales(scene: Path, gt: dict) -> dict[int, float]:
    """{id: free scale of the true mesh registered at its true pose} (observed points and
    silhouette as diagnose uses them); 1 for an unbiased fit on an unbiased sensor."""
    from r2s.diagnose.measure.observe import object_points_camera
    from r2s.diagnose.measure.scale_fit import SurfaceModel, fit_prior_scale, free_space
    from r2s.io.input_scene import load_input
    from r2s.io.mesh_io import load_mesh

    inp = load_input(scene)
    out = {}
    for g in gt["objects"]:
        pts = object_points_camera(inp, int(g["id"]))
        if len(pts) < 30:
            continue
        view = free_space(inp.camera.K, inp.depth_m, inp.masks == int(g["id"]))
        start = np.linalg.inv(np.asarray(g["world_from_object"])) @ inp.camera.world_from_camera
        fit = fit_prior_scale(SurfaceModel(load_mesh(scene / "gt" / g["mesh"])), pts, start,
                              view=view, free_space_weight=0.5)
        out[int(g["id"])] = fit.scale
    return out


def scene_rows(scene: Path, settings: MeasureSettings, true_mesh: bool = False) -> dict:
    paths = ScenePaths(scene)
    gt = json.loads(paths.gt_scene.read_text())
    s, o = injected_bias(gt)
    prior_err = {int(g["id"]): float(np.exp(np.mean(np.log(g["prior_error"]["scale"]))))
                 for g in gt["objects"] if g.get("prior_error")}
    measured = measure_scene(scene, settings, model={})
    res = measured.residuals
    reg = res.registration
    used = {x.id for x in reg.used()}
    true = true_mesh_scales(scene, gt) if true_mesh else {}
    objs = []
    for x in reg.objects:
        z_true = (x.depth_m - o) / s
        # a prior k times too large registers with the scale 1/k
        expected = (s + o / z_true) / prior_err.get(x.id, 1.0)
        objs.append({"id": x.id, "n_points": x.n_points, "depth_m": x.depth_m,
                     "fitness": x.fitness, "scale": x.scale,
                     "prior_geomean": prior_err.get(x.id), "expected": expected,
                     "fit_error_log": float(np.log(x.scale / expected)),
                     "true_mesh_scale": true.get(x.id),
                     "used": x.id in used})
    ev = offset_evidence(res.table_shape)
    fits = {}
    for name in ("depth_scale", "depth_offset"):
        eff = get_effect(name)
        fit = eff.fit(res)
        bar = eff.noise_bar(res, eff.n_params, 200, 0.99, 0) if fit.identifiable else None
        fits[name] = {"size": fit.size, "explained": fit.explained_sse, "bar": bar}
    return {"scene": scene.name, "injected": [s, o], "sigma": reg.scale_sigma,
            "dof": reg.noise_dof, "objects": objs,
            "table": None if ev is None else [ev.offset_m, ev.sigma_m], "fits": fits}


def print_scene(r: dict) -> None:
    print(f"== {r['scene']}  injected s={r['injected'][0]} o={r['injected'][1]}  "
          f"sigma={r['sigma']:.4f} dof={r['dof']}")
    for x in r["objects"]:
        print(f"  id {x['id']:2d} n={x['n_points']:5d} z={x['depth_m']:.3f} fit={x['fitness']:.2f} "
              f"scale={x['scale']:.4f} prior={x['prior_geomean'] or float('nan'):.4f} "
              f"expected={x['expected']:.4f} fit_err={100 * x['fit_error_log']:+.1f}% "
              + (f"true-mesh={x['true_mesh_scale']:.4f} " if x.get("true_mesh_scale") else "")
              + ("" if x["used"] else "(left out)"))
    used = [x for x in r["objects"] if x["used"]]
    if used:
        logs = np.log([x["scale"] for x in used])
        errs = np.array([x["fit_error_log"] for x in used])
        print(f"  mean log scale {100 * logs.mean():+.2f}% (se {100 * r['sigma'] / np.sqrt(len(used)):.2f}%)"
              f"  mean fit error {100 * errs.mean():+.2f}%  rms fit error {100 * np.sqrt(np.mean(errs ** 2)):.2f}%")
    if r["table"]:
        print(f"  table offset {1000 * r['table'][0]:+.1f} +- {1000 * r['table'][1]:.1f} mm")
    for name, f in r["fits"].items():
        print(f"  {name}: size {f['size']}, explained {f['explained']:.2f}, bar {f['bar']}")


def summarise(rows: list[dict], true_logs: list[float]) -> None:
    """Over the scenes without a depth bias: the spread of the log scales within a scene
    (what the noise level estimates) and their mean (the registration's bias)."""
    ss, dof, logs = 0.0, 0, []
    for r in rows:
        if r["injected"] != [1.0, 0.0]:
            continue
        x = np.log([o["scale"] for o in r["objects"] if o["used"]])
        if len(x) >= 2:
            ss += float(np.sum((x - x.mean()) ** 2))
            dof += len(x) - 1
        logs += list(x)
    if dof:
        print(f"unbiased scenes: {len(logs)} priors, within-scene spread of log scale "
              f"{100 * np.sqrt(ss / dof):.2f} % ({dof} dof), mean {100 * np.mean(logs):+.2f} %")
    if true_logs:
        t = np.asarray(true_logs)
        print(f"true meshes at true poses: {len(t)} objects, log scale mean "
              f"{100 * t.mean():+.2f} %, RMS {100 * np.sqrt(np.mean(t ** 2)):.2f} %")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("scenes", nargs="+", type=Path)
    ap.add_argument("--json", type=Path, default=None, help="write every row here")
    ap.add_argument("--true-mesh", action="store_true",
                    help="also register each object's true mesh at its true pose")
    args = ap.parse_args()
    settings = replace(MeasureSettings(), physics=False, table_shape_sigma_m=0.0004)
    rows = []
    true_logs = []
    for scene in args.scenes:
        r = scene_rows(scene, settings, args.true_mesh)
        print_scene(r)
        rows.append(r)
        if r["injected"] == [1.0, 0.0]:
            true_logs += [np.log(x["true_mesh_scale"]) for x in r["objects"]
                          if x["used"] and x.get("true_mesh_scale")]
        sys.stdout.flush()
    summarise(rows, true_logs)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
