#!/usr/bin/env python
"""Benchmark of the ``texture`` stage: time and PSNR / SSIM before and after refinement.

Without arguments it builds a synthetic 6-object scene (tests/helpers_texture.py: boxes,
cylinders and spheres with known textures, a 640x480 view with occlusions, an ``init``
state whose meshes carry dulled vertex colours) in a temporary folder and runs the stage
on it. With ``--scene DIR`` it runs the stage on a scene that already has a geometry state
(init / geomopt / physopt); the scene's texture/ folder is replaced.

Usage:
  python scripts/bench_texture.py [--scene DIR] [--set key=value ...] [--repeat N]
Prints the stage time (wall and CPU seconds), its phases and the metrics.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

from r2s.runner.base import run_stage  # noqa: E402
from r2s.stages.texture import STAGE, Options  # noqa: E402


def synthetic_scene(root: Path, width: int, height: int) -> Path:
    from helpers_texture import (render_view, six_object_scene, table_camera, vertex_coloured,
                                 write_scene)

    objects = six_object_scene(texture_size=256, seed=0)
    K, world_from_camera = table_camera(width, height)
    view = render_view(objects, K, world_from_camera, width, height, noise_sigma=0.01)
    return write_scene(root / "synthetic6", objects, view, [vertex_coloured(o) for o in objects])


def parse_sets(items: list[str]) -> dict:
    out = {}
    for item in items:
        key, _, value = item.partition("=")
        out[key] = json.loads(value) if value[:1] in "0123456789-[{tf" else value
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--scene", type=Path, default=None)
    ap.add_argument("--set", action="append", default=[], help="texture option key=value")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    args = ap.parse_args()
    options = Options(**parse_sets(args.set))
    with tempfile.TemporaryDirectory() as tmp:
        scene = args.scene or synthetic_scene(Path(tmp), args.width, args.height)
        for _ in range(args.repeat):
            t0, c0 = time.perf_counter(), time.process_time()
            result = run_stage(STAGE, scene, options, force=True)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            metrics = json.loads((scene / "texture" / "metrics.json").read_text())
            objects = len(metrics["objects"])
            print(f"texture stage, {objects} objects, {scene.name}: {wall:.1f} s wall, "
                  f"{cpu:.1f} s CPU; phases {metrics['seconds']}")
            s = result.summary
            print(f"  PSNR {s['psnr_before']:.2f} -> {s['psnr_after']:.2f} dB, "
                  f"SSIM {s['ssim_before']:.3f} -> {s['ssim_after']:.3f} (object pixels)")
        print(f"  options: {options.model_dump()}")


if __name__ == "__main__":
    main()
