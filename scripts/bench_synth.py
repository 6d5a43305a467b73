#!/usr/bin/env python
"""Benchmark ``r2s synth``: seconds per scene (wall and CPU) for a few seeds.

Usage:
  python scripts/bench_synth.py --objects ycb --count 6 --seeds 0,1,2 --width 640 --height 480
Convex decompositions are memoised per user (``~/.cache/r2s/convex``); the first scene that
uses a hollow object pays CoACD once (warm the whole catalogue with
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--objects", default="ycb")
    ap.add_argument("--count", type=int, default=6)
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--noise", type=float, default=1.0)
    ap.add_argument("--cold", action="store_true", help="use an empty decomposition memo")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        cache = str(Path(tmp) / "cache") if args.cold else None
        rows = []
        for seed in [int(s) for s in args.seeds.split(",")]:
            opts = SynthOptions(objects=args.objects, count=args.count, seed=seed,
                                noise=args.noise, width=args.width, height=args.height,
                                cache_dir=cache)
            wall, cpu = time.perf_counter(), time.process_time()
            summary = synthesize(Path(tmp) / f"scene_{seed}", opts)
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            rows.append((seed, summary, wall, cpu))
            print(f"seed {seed}: {summary['objects']} objects ({summary['visible']} visible, "
                  f"{summary['stacked']} stacked, {summary['contacts']} contacts) "
                  f"wall {wall:.1f} s, cpu {cpu:.1f} s", flush=True)
        walls = [r[2] for r in rows]
        cpus = [r[3] for r in rows]
        print(f"mean per scene: wall {sum(walls) / len(walls):.1f} s, "
              f"cpu {sum(cpus) / len(cpus):.1f} s")


if __name__ == "__main__":
    main()
