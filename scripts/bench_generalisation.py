#!/usr/bin/env python
"""Scenes unlike the benchmark's: other objects, more of them, undeclared effects.

The main benchmark (scripts/bench.py) uses YCB objects, 4-10 per scene, and a sensor and
camera that are as declared. The scenes an outside judge sees may differ in all three. This
script synthesises scenes with pybullet_data's random objects or a YCB/pybullet mix, up to
15 objects, each (but one) with an effect injected by ``r2s synth --effect`` and declared
nowhere, runs ``r2s run`` on each (every stage, no diagnose), and judges the export the way
an outside judge would, under the four settings of scripts/bench_judge_variants.py.

Usage:
  python scripts/bench_generalisation.py --out docs/generalisation.md
Scenes live in bench/generalisation/<name> and are reused when their export exists.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "scripts"))

from bench_judge_variants import VARIANTS, judge  # noqa: E402
from doc_block import write_generated_block  # noqa: E402

SCENES: list[tuple[str, str, int, int, str]] = [
    # name, object set, objects, synth seed, undeclared effect ("" for none)
    ("pyb6", "pybullet", 6, 11, ""),
    ("mix7_scale", "mixed", 7, 12, "depth_scale=1.02"),
    ("pyb5_camrot", "pybullet", 5, 13, "camera_rotation_deg=2"),
    ("mix8_com", "mixed", 8, 14, "com_offset_m=0.02"),
    ("pyb8_offset", "pybullet", 8, 15, "depth_offset_m=0.008"),
    ("mix6_tilt", "mixed", 6, 16, "table_tilt_deg=2"),
    ("ycb15_scale", "ycb", 15, 21, "depth_scale=0.98"),
    ("mix13_camrot", "mixed", 13, 22, "camera_rotation_deg=1.5"),
]


def r2s(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "r2s.cli", *args], check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def run_scene(root: Path, name: str, objects: str, count: int, seed: int, effect: str) -> dict:
    scene = root / name
    record = scene / "bench_generalisation.json"
    if record.is_file() and (scene / "export" / "scene.json").is_file():
        return json.loads(record.read_text())
    if not (scene / "gt" / "scene.json").is_file():
        args = ["synth", str(scene), "--objects", objects, "--count", str(count),
                "--seed", str(seed)]
        if effect:
            args += ["--effect", effect]
        r2s(*args)
    t0 = time.perf_counter()
    r2s("run", str(scene))
    seconds = time.perf_counter() - t0
    metrics = json.loads((scene / "evaluate" / "metrics.json").read_text())
    judged = []
    for duration, rate in VARIANTS:
        res = judge(scene / "export", duration, rate)
        judged.append([sum(res.values()), len(res), [i for i, ok in res.items() if not ok]])
    out = {"name": name, "objects": objects, "count": judged[0][1],
           "effect": effect or "-", "seconds": seconds,
           "chamfer_mm": metrics.get("chamfer_mm"),
           "centroid_error_mm": metrics.get("centroid_error_mm"),
           "max_penetration_mm": metrics.get("max_penetration_mm"), "judged": judged}
    record.write_text(json.dumps(out, indent=1))
    return out


def table(rows: list[dict]) -> str:
    names = [f"{d:g} s @ {r:g} Hz" for d, r in VARIANTS]
    lines = ["| scene | objects | undeclared effect | `r2s run` [s] | CD [mm] | centroid err [mm] "
             "| max penetration [mm] | " + " | ".join(names) + " |",
             "|---|---|---|---:|---:|---:|---:|" + "---|" * len(VARIANTS)]
    totals = [[0, 0] for _ in VARIANTS]
    for r in rows:
        cells = []
        for k, (ok, n, bad) in enumerate(r["judged"]):
            totals[k][0] += ok
            totals[k][1] += n
            cells.append(f"{ok}/{n}" + (f" (moving: {', '.join(map(str, bad))})" if bad else ""))
        lines.append(f"| {r['name']} | {r['count']} {r['objects']} | {r['effect']} | "
                     f"{r['seconds']:.0f} | {r['chamfer_mm']:.1f} | {r['centroid_error_mm']:.1f} | "
                     f"{r['max_penetration_mm']:.1f} | " + " | ".join(cells) + " |")
    lines.append("| **all** | | | | | | | " + " | ".join(
        f"**{100.0 * a / max(b, 1):.1f}%** ({a}/{b})" for a, b in totals) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--root", type=Path, default=REPO / "bench" / "generalisation")
    ap.add_argument("--out", type=Path, default=None, help="markdown file to update")
    args = ap.parse_args()
    rows = []
    for spec in SCENES:
        rows.append(run_scene(args.root, *spec))
        print(f"{spec[0]}: {rows[-1]['judged'][0][0]}/{rows[-1]['judged'][0][1]} stable, "
              f"{rows[-1]['seconds']:.0f} s", flush=True)
    text = table(rows)
    print(text)
    if args.out:
        write_generated_block(args.out, "bench_generalisation", text)


if __name__ == "__main__":
    main()
