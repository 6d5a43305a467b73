#!/usr/bin/env python
"""Does the objects' depth follow their printed texture? One line per scene.

Runs r2s/diagnose/stats/texture_depth.py's test on each scene's input/ (depth.png, rgb.png
and masks.png as they are), or with a colour-dependent depth error added first: every
valid pixel reads ``--dark-mm`` x (1 - luminance) mm farther (Rec. 601 luminance of
rgb.png, 0..1), rounded to the scene's depth unit as a depth PNG would store it. That is
the benchmark's ``dark_depth`` case (scripts/bench_diagnose.py) without writing a scene,
so the same scenes give the test's level with and without the error (docs/diagnose.md,
section 6). Nothing is written.

Usage:
  python scripts/texture_depth_scan.py SCENE [SCENE ...] [--dark-mm 8]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "scripts"))

from bench_diagnose import dark_depth_bias_m  # noqa: E402
from r2s.diagnose.measure.observe import grey_image  # noqa: E402
from r2s.diagnose.stats.texture_depth import test_texture_depth  # noqa: E402
from r2s.io.input_scene import load_camera, load_input  # noqa: E402


def with_dark_error(depth_m: np.ndarray, rgb: np.ndarray, error_black_m: float,
                    unit_m: float) -> np.ndarray:
    """(H, W) depth m with the benchmark's colour error (``bench_diagnose.
    dark_depth_bias_m``) added where it reads, rounded to ``unit_m``."""
    if error_black_m == 0:
        return depth_m
    bias = dark_depth_bias_m(rgb, error_black_m)
    valid = np.isfinite(depth_m) & (depth_m > 0)
    out = np.array(depth_m, dtype=np.float64)
    out[valid] = np.round((out[valid] + bias[valid]) / unit_m) * unit_m
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="+", type=Path)
    ap.add_argument("--dark-mm", type=float, default=0.0)
    args = ap.parse_args()
    zs = []
    for root in args.scenes:
        scene = load_input(root)
        depth = with_dark_error(scene.depth_m, scene.rgb, args.dark_mm / 1000.0,
                                load_camera(root / "input" / "camera.json")[1])
        found = test_texture_depth(depth, grey_image(scene), scene.masks)
        if found is None:
            print(f"{root}: no test (too few patches with print)")
            continue
        zs.append(found.z)
        print(f"{root}: z {found.z:+.1f}, slope {found.slope_mm:+.2f} mm per unit grey, "
              f"{len(found.slopes_mm)} objects" + ("  REPORTED" if found.structured else ""))
    if zs:
        reported = sum(abs(z) >= 6.0 for z in zs)
        print(f"{len(zs)} scenes tested: |z| median {np.median(np.abs(zs)):.1f}, max "
              f"{np.max(np.abs(zs)):.1f}; reported (|z| >= 6) {reported}")


if __name__ == "__main__":
    main()
