#!/usr/bin/env python
"""What a lens distortion costs the reconstruction, and what undistorting gains back,
read against the scene without it.

`scripts/bench_diagnose.py` makes its ``lens_distortion`` scene of seed S from its clean
scene of seed S (same objects, camera and priors) with the distortion added. For each
seed this runs ``r2s init`` on copies of three scenes: the clean one, the distorted one,
and the distorted one with the injected (true) k1, k2 kept in its manifest's model, as
``r2s diagnose --set apply=true`` would keep a fit. It prints the gt centroid error of
init's state (mean over objects, mm) and the table normal's error (deg) of each.

Usage:
  python scripts/lens_twin_check.py [--root bench/diagnose] [--seeds 0,1,2,3,4,5]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.diagnose.measure.scene_dir import scene_gt_errors  # noqa: E402
from r2s.io.manifest import load_manifest, save_manifest  # noqa: E402
from r2s.io.paths import ScenePaths  # noqa: E402
from r2s.scene_model import with_effect  # noqa: E402


def _copy(src: Path, dst: Path) -> Path:
    dst.mkdir(parents=True)
    for part in ("input", "gt"):
        shutil.copytree(src / part, dst / part)
    return dst


def _init_errors(scene: Path, lens: dict | None = None) -> tuple[float, float]:
    """(gt centroid error mm, table normal error deg) after ``r2s init`` on ``scene``,
    with ``lens`` (k1, k2) kept in the model first when given."""
    if lens is not None:
        paths = ScenePaths(scene)
        manifest = load_manifest(paths.manifest)
        manifest.model = with_effect(manifest.model, "lens_distortion", dict(lens))
        save_manifest(paths.manifest, manifest)
    subprocess.run([sys.executable, "-m", "r2s.cli", "init", str(scene)], cwd=REPO,
                   check=True, capture_output=True)
    e = scene_gt_errors(scene)
    return e["state_centroid_error_mm"], e["state_support_normal_error_deg"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", type=Path, default=REPO / "bench" / "diagnose")
    ap.add_argument("--seeds", default="0,1,2,3,4,5")
    args = ap.parse_args()
    print("| seed | clean | distorted | undistorted (true k1) "
          "| table normal error [deg], distorted -> undistorted |")
    print("|---|---:|---:|---:|---|")
    for seed in (int(s) for s in args.seeds.split(",")):
        distorted_src = args.root / f"lens_distortion_s{seed}"
        lens = scene_gt_errors(distorted_src)["injected_effects"]["lens_distortion"]
        with tempfile.TemporaryDirectory(prefix="r2s-lens-") as tmp:
            clean, _ = _init_errors(_copy(args.root / f"clean_s{seed}", Path(tmp) / "clean"))
            raw, raw_n = _init_errors(_copy(distorted_src, Path(tmp) / "distorted"))
            fixed, fixed_n = _init_errors(_copy(distorted_src, Path(tmp) / "undistorted"), lens)
        print(f"| {seed} | {clean:.2f} | {raw:.2f} | {fixed:.2f} | {raw_n:.3f} -> {fixed_n:.3f} |",
              flush=True)


if __name__ == "__main__":
    main()
