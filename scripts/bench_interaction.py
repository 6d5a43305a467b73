#!/usr/bin/env python
"""Benchmark of using the twin: push prediction, decluttering, stability in two engines.

On the scenes of scripts/bench.py (same generator, seeds and object counts: scene k is
``r2s synth`` with seed ``seed * 1000 + k``), each scene gets an observed push made on its
ground truth (``r2s.synth.push.add_observed_push``: input/interaction/, gt/push.json).
Then per method (one after the other, since all export to export/):

  gt        the ground truth exported as is (the floor: sensor noise, PyBullet's margins)
  baseline  init -> export                        (the paper's SAM3D+ICP)
  full      init -> graph -> geomopt -> physopt -> export

and for each: ``r2s predict`` of the observed push (UCD of the observed points after the
push to the predicted meshes, pose error of the predicted motion against gt/push.json),
``r2s declutter`` (its removal order replayed on the ground truth), and ``r2s evaluate``
with engine=pybullet and engine=mujoco (stability).

Usage (regenerates the table in docs/interaction.md between its bench markers):
  python scripts/bench_interaction.py --scenes 10 --seed 0 --out docs/interaction.md
Scenes live in bench/interaction/scene_XX (reused; stages are cached by staleness);
per-method figures are kept in scene_XX/bench_interaction/<method>.json, so
``--table-only`` rebuilds the table without running anything.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "scripts"))

from bench import METHOD_STAGES, synth_scenes  # noqa: E402
from doc_block import write_generated_block  # noqa: E402
from r2s.io.paths import ScenePaths  # noqa: E402
from r2s.runner.pipeline import build_options  # noqa: E402
from r2s.runner.base import run_stage  # noqa: E402
from r2s.runner.registry import get_stage  # noqa: E402

RESULTS = "bench_interaction"


def add_push(scene: Path) -> dict:
    from r2s.synth.push import add_observed_push

    paths = ScenePaths(scene)
    if paths.gt_push.is_file() and paths.push_action.is_file():
        return {"pushed_id": json.loads(paths.gt_push.read_text())["pushed_id"]}
    t0 = time.perf_counter()
    out = add_observed_push(scene)
    print(f"push {scene.name}: object {out['pushed_id']} moved {out['displacement_m'] * 1000:.0f}"
          f" mm, others at most {out['others_max_m'] * 1000:.1f} mm "
          f"({time.perf_counter() - t0:.0f} s)", flush=True)
    return out


def _stage(scene: Path, name: str, force: bool, **overrides: object) -> None:
    spec = get_stage(name)
    run_stage(spec, scene, build_options(spec, None, {k: str(v) for k, v in overrides.items()}),
              force=force)


def _stability(scene: Path) -> dict:
    m = json.loads(ScenePaths(scene).metrics.read_text())
    objs = m.get("objects", [])
    return {"stable": sum(1 for o in objs if o.get("stable")), "objects": len(objs)}


def run_method(scene: Path, method: str) -> dict:
    """Reconstruct with ``method``, then predict, declutter and evaluate in both engines."""
    from r2s.interaction.declutter import declutter
    from r2s.interaction.predict import predict

    t0 = time.perf_counter()
    stages, source = METHOD_STAGES[method]
    for name in stages:
        _stage(scene, name, force=False)
    _stage(scene, "export", force=True, source=source)
    err = predict(scene)["error"]
    plan = declutter(scene)
    out = {"scene": scene.name, "method": method, "push": err,
           "declutter": {"order": plan["order"], "success_rate": plan["success_rate"],
                         "gt_success_rate": plan["ground_truth"]["success_rate"],
                         "gt_steps": plan["ground_truth"]["steps"]}}
    for engine in ("pybullet", "mujoco"):
        _stage(scene, "evaluate", force=True, engine=engine, render=False)
        out[engine] = _stability(scene)
    out["seconds"] = time.perf_counter() - t0
    dest = scene / RESULTS / f"{method}.json"
    dest.parent.mkdir(exist_ok=True)
    dest.write_text(json.dumps(out, indent=1))
    return out


def _mean_median(values: list) -> str:
    vals = [float(v) for v in values if v is not None]
    if not vals:
        return "-"
    return f"{np.mean(vals):.1f} / {np.median(vals):.1f}"


def table(rows_by_method: dict[str, list[dict]]) -> str:
    head = ("| Method | Scenes | Push UCD [mm] mean / median | Pushed object UCD [mm] | "
            "Pushed object pose error [mm] | Pushed object pose error [deg] | "
            "Declutter: own plan at rest [%] | Declutter: replayed on gt [%] | "
            "Stable, PyBullet [%] | Stable, MuJoCo [%] |")
    lines = [head, "|" + "|".join(["---"] * (head.count("|") - 1)) + "|"]
    for method, rows in rows_by_method.items():
        if not rows:
            continue
        push = [r["push"] for r in rows]

        def pct(engine: str) -> str:
            stable = sum(r[engine]["stable"] for r in rows)
            total = sum(r[engine]["objects"] for r in rows)
            return f"{100.0 * stable / total:.1f}" if total else "-"

        lines.append(" | ".join([
            f"| {method}", str(len(rows)),
            _mean_median([p.get("ucd_mm") for p in push]),
            _mean_median([p.get("pushed_ucd_mm") for p in push]),
            _mean_median([p.get("pushed_translation_mm") for p in push]),
            _mean_median([p.get("pushed_rotation_deg") for p in push]),
            f"{100.0 * np.mean([r['declutter']['success_rate'] for r in rows]):.1f}",
            f"{100.0 * np.mean([r['declutter']['gt_success_rate'] for r in rows]):.1f}",
            pct("pybullet"), pct("mujoco")]) + " |")
    return "\n".join(lines) + "\n"


def per_scene(rows_by_method: dict[str, list[dict]]) -> str:
    """Scene UCD per method, a column per method (mm)."""
    methods = [m for m, rows in rows_by_method.items() if rows]
    scenes = sorted({r["scene"] for m in methods for r in rows_by_method[m]})
    lines = ["| Scene | pushed | " + " | ".join(f"UCD {m} [mm]" for m in methods) + " |",
             "|" + "|".join(["---"] * (len(methods) + 2)) + "|"]
    for s in scenes:
        cells, pushed = [], "-"
        for m in methods:
            r = next((r for r in rows_by_method[m] if r["scene"] == s), None)
            ucd = r["push"].get("ucd_mm") if r else None
            cells.append("-" if ucd is None else f"{ucd:.1f}")
            pushed = str(r["push"].get("pushed_id")) if r else pushed
        lines.append(f"| {s} | {pushed} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--scenes", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--min-objects", type=int, default=4)
    ap.add_argument("--max-objects", type=int, default=10)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--methods", default="gt,baseline,full")
    ap.add_argument("--root", type=Path, default=REPO / "bench" / "interaction")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--table-only", action="store_true",
                    help="Rebuild the table from the per-scene results; run nothing.")
    args = ap.parse_args()
    methods = args.methods.split(",")

    if args.table_only:
        scenes = [args.root / f"scene_{k:02d}" for k in range(args.scenes)]
    else:
        scenes = synth_scenes(args.root, args.scenes, args.seed, args.min_objects,
                              args.max_objects, args.width, args.height)
    rows: dict[str, list[dict]] = {m: [] for m in methods}
    for scene in scenes:
        if not args.table_only:
            add_push(scene)
        for method in methods:
            result = scene / RESULTS / f"{method}.json"
            if args.table_only:
                if result.is_file():
                    rows[method].append(json.loads(result.read_text()))
                continue
            r = run_method(scene, method)
            rows[method].append(r)
            p = {k: float("nan") if v is None else v for k, v in r["push"].items()}
            print(f"{method} {scene.name}: UCD {p['ucd_mm']:.1f} mm, "
                  f"pushed {p['pushed_translation_mm']:.1f} mm / "
                  f"{p['pushed_rotation_deg']:.1f} deg, declutter on gt "
                  f"{r['declutter']['gt_success_rate']:.0%}, stable pybullet "
                  f"{r['pybullet']['stable']}/{r['pybullet']['objects']} mujoco "
                  f"{r['mujoco']['stable']}/{r['mujoco']['objects']} ({r['seconds']:.0f} s)",
                  flush=True)
    block = table(rows) + "\nScene UCD per scene:\n\n" + per_scene(rows)
    print(block)
    if args.out:
        write_generated_block(args.out, "bench_interaction", block)


if __name__ == "__main__":
    main()
