#!/usr/bin/env python
"""`r2s batch` with one job against two: wall time and the ratio (issue 17's bar: <= 0.6x).

Makes N small synthetic scenes once (``r2s synth SCENE --count C --seed K --width W
--height H``) under ROOT/inputs/, then, R times and alternating the order, copies their
``input/`` and ``gt/`` to a fresh batch root and times

    r2s batch BATCH_ROOT --jobs J --skip texture

for J = 1 and J = 2 (each job capped at one torch/BLAS thread by ``r2s batch``). Prints
every run, the median wall time per J and the ratio of the medians; ``--out`` writes the
table into a markdown file. The machine must be otherwise idle for the ratio to mean what
it says.

Usage:
  python scripts/bench_batch.py --scenes 4 --repeats 2 --out docs/batch.md
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts"))

from doc_block import write_generated_block  # noqa: E402


def _r2s(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "r2s.cli", *args], cwd=REPO,
                          capture_output=True, text=True)


def make_inputs(root: Path, args: argparse.Namespace) -> list[Path]:
    scenes = []
    for k in range(args.scenes):
        scene = root / "inputs" / f"scene_{k:02d}"
        if not (scene / "input" / "camera.json").is_file():
            done = _r2s("synth", str(scene), "--count", str(args.count), "--seed", str(k),
                        "--width", str(args.width), "--height", str(args.height))
            if done.returncode != 0:
                raise SystemExit(f"synth failed: {done.stderr.strip()[-300:]}")
        scenes.append(scene)
    return scenes


def time_batch(root: Path, scenes: list[Path], jobs: int) -> float:
    batch_root = root / f"batch_jobs{jobs}"
    shutil.rmtree(batch_root, ignore_errors=True)
    for scene in scenes:
        for part in ("input", "gt"):
            if (scene / part).is_dir():
                shutil.copytree(scene / part, batch_root / scene.name / part)
    t0 = time.perf_counter()
    done = _r2s("batch", str(batch_root), "--jobs", str(jobs), "--skip", "texture")
    seconds = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"r2s batch --jobs {jobs} failed: {done.stderr.strip()[-300:]}")
    return seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", type=Path, default=REPO / "bench" / "batch")
    ap.add_argument("--scenes", type=int, default=4)
    ap.add_argument("--count", type=int, default=3, help="objects per scene")
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None, help="markdown file to update")
    args = ap.parse_args()

    scenes = make_inputs(args.root, args)
    times: dict[int, list[float]] = {1: [], 2: []}
    for r in range(args.repeats):
        for jobs in ((1, 2) if r % 2 == 0 else (2, 1)):
            seconds = time_batch(args.root, scenes, jobs)
            times[jobs].append(seconds)
            print(f"repeat {r + 1}: --jobs {jobs}: {seconds:.1f} s", flush=True)
    med = {j: statistics.median(v) for j, v in times.items()}
    lines = ["| jobs | runs [s] | median [s] | ratio to --jobs 1 |", "|---|---|---:|---:|"]
    for j in (1, 2):
        runs = ", ".join(f"{s:.1f}" for s in times[j])
        lines.append(f"| {j} | {runs} | {med[j]:.1f} | {med[j] / med[1]:.2f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        write_generated_block(args.out, "bench_batch", text)


if __name__ == "__main__":
    main()
