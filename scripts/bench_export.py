#!/usr/bin/env python
"""Benchmark of the exported physics: mass error against gt and the stable fraction judged
in PyBullet (URDF-equivalent scene.json) and in MuJoCo (export/scene.xml), same criterion.

For each scene (already run up to geomopt, e.g. by ``r2s run``) and each mass prior:
  density600   physopt's mass prior at the former fixed 600 kg/m^3 (the old behaviour)
  table        physopt's mass prior from the label density table (the default now)
the script reruns physopt -> texture -> export, then evaluate with engine=pybullet and
engine=mujoco, and pools objects over scenes. Also the gt row (gt/ exported as is).

Usage:
  python scripts/bench_export.py SCENE [SCENE ...] [--out docs/physics_parameters.md]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.io.paths import ScenePaths  # noqa: E402
from r2s.runner.pipeline import build_options  # noqa: E402
from r2s.runner.base import run_stage  # noqa: E402
from r2s.runner.registry import get_stage  # noqa: E402

PRIORS = {"density600": {"density_kg_m3": 600.0}, "table": {}}


def _run(scene: Path, name: str, overrides: dict) -> None:
    spec = get_stage(name)
    run_stage(spec, scene, build_options(spec, None, overrides), force=True)


def _judge(scene: Path) -> dict:
    out = {}
    for engine in ("pybullet", "mujoco"):
        _run(scene, "evaluate", {"engine": engine, "render": "false"})
        out[engine] = json.loads(ScenePaths(scene).metrics.read_text())
    return out


def run_scene(scene: Path, prior: str) -> dict:
    if prior == "gt":
        _run(scene, "export", {"source": "gt"})
    else:
        _run(scene, "physopt", PRIORS[prior])
        _run(scene, "texture", {})
        _run(scene, "export", {})
    return _judge(scene)


def pooled(results: list[dict]) -> dict:
    row = {}
    for engine in ("pybullet", "mujoco"):
        objs = [o for r in results for o in r[engine]["objects"]]
        row[f"stable_{engine}_pct"] = 100.0 * sum(o["stable"] for o in objs) / len(objs)
    objs = [o for r in results for o in r["pybullet"]["objects"]]
    errs = [o["mass_rel_error"] for o in objs if o.get("mass_rel_error") is not None]
    row["mass_rel_error_mean"] = float(np.mean(errs))
    row["mass_rel_error_median"] = float(np.median(errs))
    row["objects"] = len(objs)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("scenes", nargs="+", type=Path)
    ap.add_argument("--priors", default="gt,density600,table")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    lines = ["| Mass prior | Scenes | Objects | Stable, PyBullet [%] | Stable, MuJoCo [%] | "
             "Mass error vs gt, mean / median [%] |", "|---|---|---|---|---|---|"]
    for prior in args.priors.split(","):
        results = []
        for scene in args.scenes:
            results.append(run_scene(scene, prior))
            r = results[-1]
            print(f"{prior} {scene.name}: pybullet {r['pybullet']['stability_ratio']:.2f} "
                  f"mujoco {r['mujoco']['stability_ratio']:.2f} "
                  f"mass err {r['pybullet']['mass_rel_error']:.2f}", flush=True)
        row = pooled(results)
        lines.append(f"| {prior} | {len(results)} | {row['objects']} | "
                     f"{row['stable_pybullet_pct']:.1f} | {row['stable_mujoco_pct']:.1f} | "
                     f"{100 * row['mass_rel_error_mean']:.1f} / "
                     f"{100 * row['mass_rel_error_median']:.1f} |")
        print(lines[-1], flush=True)
    table = "\n".join(lines) + "\n"
    print(table)
    if args.out:
        sys.path.insert(0, str(REPO / "scripts"))
        from doc_block import write_generated_block

        write_generated_block(args.out, "bench_export", table)


if __name__ == "__main__":
    main()
