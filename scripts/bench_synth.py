#!/usr/bin/env python
"""Benchmark ``r2s synth``: seconds per scene (wall and CPU) for a few seeds.

Usage:
  python scripts/bench_synth.py --objects ycb --count 6 --seeds 0,1,2 --width 640 --height 480
  python scripts/bench_synth.py --seeds 0-9 --judge      # also gt -> export -> evaluate
Convex decompositions are memoised per user (``~/.cache/r2s/convex``); the first scene that
uses a concave object pays its decomposition once (warm the whole catalogue with
``python -m r2s.synth.warm_cache``). ``--cold`` uses an empty memo to measure that cost.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.synth.generate import SynthOptions, synthesize  # noqa: E402


def judge(scene: Path) -> tuple[int, int]:
    """Run export (source=gt) and evaluate on a scene; (stable objects, objects)."""
    import json

    from r2s.runner.pipeline import build_options
    from r2s.runner.base import run_stage
    from r2s.runner.registry import get_stage

    export, evaluate = get_stage("export"), get_stage("evaluate")
    run_stage(export, scene, build_options(export, None, {"source": "gt"}), force=True)
    run_stage(evaluate, scene, build_options(evaluate, None, {"render": False}), force=True)
    metrics = json.loads((scene / "evaluate" / "metrics.json").read_text())
    objects = metrics.get("objects", [])
    return sum(1 for o in objects if o.get("stable")), len(objects)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--objects", default="ycb")
    ap.add_argument("--count", type=int, default=6)
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--noise", type=float, default=1.0)
    ap.add_argument("--effect", action="append", default=[], help="NAME=VALUE (repeatable)")
    ap.add_argument("--cold", action="store_true", help="use an empty decomposition memo")
    ap.add_argument("--judge", action="store_true",
                    help="export the ground truth and evaluate it (stability must be ~100%%)")
    args = ap.parse_args()
    if "-" in args.seeds:
        lo, hi = (int(x) for x in args.seeds.split("-"))
        seeds = list(range(lo, hi + 1))
    else:
        seeds = [int(s) for s in args.seeds.split(",")]
    effects = dict(e.split("=", 1) for e in args.effect)

    with tempfile.TemporaryDirectory() as tmp:
        cache = str(Path(tmp) / "cache") if args.cold else None
        rows = []
        stable = total = 0
        for seed in seeds:
            opts = SynthOptions(objects=args.objects, count=args.count, seed=seed,
                                noise=args.noise, width=args.width, height=args.height,
                                effects=effects, cache_dir=cache)
            wall, cpu = time.perf_counter(), time.process_time()
            summary = synthesize(Path(tmp) / f"scene_{seed}", opts)
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            rows.append((seed, summary, wall, cpu))
            print(f"seed {seed}: {summary['objects']} objects ({summary['visible']} visible, "
                  f"{summary['stacked']} stacked, {summary['contacts']} contacts) "
                  f"wall {wall:.1f} s, cpu {cpu:.1f} s", flush=True)
            if args.judge:
                ok, n = judge(Path(tmp) / f"scene_{seed}")
                stable, total = stable + ok, total + n
                print(f"  judge: {ok}/{n} stable", flush=True)
        walls = [r[2] for r in rows]
        cpus = [r[3] for r in rows]
        print(f"mean per scene: wall {sum(walls) / len(walls):.1f} s, "
              f"cpu {sum(cpus) / len(cpus):.1f} s")
        if args.judge:
            print(f"gt -> export -> evaluate: {stable}/{total} objects stable "
                  f"({100.0 * stable / max(total, 1):.1f} %)")


if __name__ == "__main__":
    main()
