"""A/B of physopt (or geomopt) options from a scene's earlier outputs: physopt, export and
evaluate rerun on two copies of each scene, one per option set, and a markdown table of the
scene metrics side by side (A -> B) on stdout.

    python scripts/ab_physopt.py bench/fresh5/* --work /tmp/ab \
        --a diffsim_guard=false --b diffsim_guard=true [--changed-only]
    python scripts/ab_physopt.py bench/fresh7/* --work /tmp/ab --stage geomopt \
        --a min_support_likelihood=0 --b min_support_likelihood=0.25

Only scenes with a geomopt stage are taken; input/, gt/, init/, graph/, geomopt/ (not with
``--stage geomopt``, which reruns it first with the options) and the manifest are copied,
the originals are not touched. ``--changed-only`` prints only the
scenes whose metrics differ. Single runs: physopt's rollouts are deterministic, its torch
step is not bit-exact across machines.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

COPIED = ("input", "gt", "init", "graph", "geomopt", "manifest.json")
METRICS = (("silhouette_iou", "IoU", 3), ("min_silhouette_iou", "min IoU", 2),
           ("ucd_mm", "UCD mm", 2), ("chamfer_mm", "CD mm", 2),
           ("centroid_error_mm", "centroid mm", 1), ("flagged_objects", "flagged", 0),
           ("stability_ratio", "at rest", 2))


def _copy(scene: Path, dst: Path, stage: str) -> None:
    if dst.exists():
        shutil.rmtree(dst)
    dst.mkdir(parents=True)
    for name in COPIED:
        if name == stage:
            continue
        src = scene / name
        if src.is_dir():
            shutil.copytree(src, dst / name)
        elif src.is_file():
            shutil.copy2(src, dst / name)


def _run(scene: Path, sets: list[str], stage: str) -> dict:
    flags = [a for s in sets for a in ("--set", s)]
    verbs = [("physopt", flags if stage == "physopt" else []), ("export", []), ("evaluate", [])]
    if stage == "geomopt":
        verbs.insert(0, ("geomopt", flags))
    for verb, extra in verbs:
        done = subprocess.run([sys.executable, "-m", "r2s.cli", verb, str(scene), *extra],
                              capture_output=True, text=True)
        if done.returncode:
            raise SystemExit(f"{verb} failed on {scene}: {done.stderr.strip()[-300:]}")
    metrics = json.loads((scene / "evaluate" / "metrics.json").read_text())
    log = json.loads((scene / "physopt" / "log.json").read_text())
    return {"metrics": metrics, "reverted": log.get("diffsim_reverted")}


def _cell(a, b, digits: int) -> str:
    if a is None or b is None:
        return "-"
    return f"{a:.{digits}f} -> {b:.{digits}f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="+", type=Path)
    ap.add_argument("--work", type=Path, required=True, help="where the copies go")
    ap.add_argument("--stage", choices=("physopt", "geomopt"), default="physopt",
                    help="the stage the options are for (it and the stages after it rerun)")
    ap.add_argument("--a", nargs="*", default=[], help="KEY=VALUE options of A")
    ap.add_argument("--b", nargs="*", default=[], help="KEY=VALUE options of B")
    ap.add_argument("--changed-only", action="store_true")
    args = ap.parse_args()
    scenes = [s for s in args.scenes if (s / "geomopt" / "state.json").is_file()]
    print("| scene | B: diffsim_reverted | " + " | ".join(m[1] for m in METRICS) + " |")
    print("|---" * (len(METRICS) + 2) + "|")
    for scene in scenes:
        name = f"{scene.parent.name}/{scene.name}"
        out = {}
        for arm, sets in (("A", args.a), ("B", args.b)):
            dst = args.work / scene.parent.name / f"{scene.name}__{arm}"
            _copy(scene, dst, args.stage)
            out[arm] = _run(dst, sets, args.stage)
        ma, mb = out["A"]["metrics"], out["B"]["metrics"]
        if args.changed_only and all(ma.get(k) == mb.get(k) for k, _, _ in METRICS):
            continue
        cells = [_cell(ma.get(k), mb.get(k), d) for k, _, d in METRICS]
        print(f"| {name} | {out['B']['reverted']} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
