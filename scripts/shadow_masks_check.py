"""Give every object of a scene's masks a shadow, and compare `r2s init` with and without it.

A segmenter often takes an object's shadow on the table into its mask. This script copies
SCENE's input/ and gt/ twice into OUT (``plain`` as it is, ``shadow`` with every object's
mask grown by ``--grow-px`` (8-connected dilation steps), shifted by ``--shift-px`` rows and
columns, onto background pixels only, objects in id order), runs `r2s init` on both, and
prints per object the largest relative extent error of the init mesh against gt/ (world
axes) without and with the shadow, and the mask pixels added. Run it with each version of
the code (``PYTHONPATH``) to compare them (docs/completion.md, "A shadow in the mask").

Usage:
  python scripts/shadow_masks_check.py bench/realistic/scene_02_noprior build/shadow_02
  python scripts/shadow_masks_check.py SCENE OUT --grow-px 10 --shift-px 6 6
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image
from scipy import ndimage


def add_shadows(masks: np.ndarray, grow_px: int, shift_px: tuple[int, int]) -> np.ndarray:
    """(H, W) ids with every object's mask grown by ``grow_px`` dilation steps, shifted by
    ``shift_px`` (rows, cols, >= 0) and written onto pixels that are background in both
    the input and what earlier objects took."""
    out = masks.copy()
    dr, dc = shift_px
    for i in np.unique(masks):
        if i == 0:
            continue
        grown = ndimage.binary_dilation(masks == i, iterations=grow_px)
        moved = np.zeros_like(grown)
        moved[dr:, dc:] = grown[:grown.shape[0] - dr, :grown.shape[1] - dc]
        out[moved & (masks == 0) & (out == 0)] = i
    return out


def extent_errors(scene: Path) -> dict[int, float]:
    """Per gt object with an init mesh: max |init extents - gt extents| / gt extents."""
    state = json.loads((scene / "init" / "state.json").read_text())
    gt = json.loads((scene / "gt" / "scene.json").read_text())
    out = {}
    for o in gt["objects"]:
        done = [s for s in state["objects"] if s["id"] == o["id"]]
        if not done:
            continue
        truth = trimesh.load(scene / "gt" / "meshes" / f"{o['id']}.glb", force="mesh")
        truth.apply_transform(np.asarray(o["world_from_object"]))
        mesh = trimesh.load(scene / "init" / done[0]["mesh"], force="mesh")
        mesh.apply_transform(np.asarray(done[0]["world_from_object"]))
        out[o["id"]] = float(np.max(np.abs(mesh.extents - truth.extents) / truth.extents))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--grow-px", type=int, default=10)
    ap.add_argument("--shift-px", type=int, nargs=2, default=(6, 6))
    args = ap.parse_args()
    labels = {}
    added = {}
    for variant in ("plain", "shadow"):
        dst = args.out / variant
        if dst.exists():
            shutil.rmtree(dst)
        shutil.copytree(args.scene / "input", dst / "input")
        shutil.copytree(args.scene / "gt", dst / "gt")
        if variant == "shadow":
            path = dst / "input" / "masks.png"
            masks = np.array(Image.open(path))
            shadowed = add_shadows(masks, args.grow_px, tuple(args.shift_px))
            Image.fromarray(shadowed.astype(masks.dtype)).save(path)
            added = {int(i): int(((shadowed == i) & (masks != i)).sum())
                     for i in np.unique(masks) if i > 0}
        subprocess.run([sys.executable, "-m", "r2s.cli", "init", str(dst)], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        labels[variant] = extent_errors(dst)
    gt = json.loads((args.scene / "gt" / "scene.json").read_text())
    names = {o["id"]: o.get("label", "") for o in gt["objects"]}
    print("id  label                      shadow px  extent error: plain  shadow")
    for i in sorted(labels["plain"]):
        plain, shad = labels["plain"][i], labels["shadow"].get(i, float("nan"))
        print(f"{i:<3} {names.get(i, ''):26s} {added.get(i, 0):9d}  {100 * plain:18.0f} % "
              f"{100 * shad:5.0f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
