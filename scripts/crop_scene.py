"""Derive a scene whose image border cuts objects: a crop of another scene's images.

Real captures are framed loosely: objects at the edge of the picture are only partly in
it. The crop keeps the camera (K's principal point moves with the crop) and the world, so
``gt/`` stays valid. ``SRC``'s ``input/`` and ``gt/`` are copied to ``DST`` with rgb.png,
depth.png and masks.png cropped to the box ``--box LEFT,TOP,RIGHT,BOTTOM`` (pixels, as
fractions of the image when all four are <= 1), camera.json's width, height and K
updated; an instance left with fewer than ``--min-px`` pixels is dropped from masks.png
and objects.json (it stays in gt/, as an object the camera did not see).

Usage::

    python scripts/crop_scene.py bench/s_A/scene_02_noprior /tmp/cropped --box 0.3,0,1,1
    r2s run /tmp/cropped --skip texture
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
from PIL import Image


def crop_box(text: str, width: int, height: int) -> tuple[int, int, int, int]:
    """(left, top, right, bottom) pixels from ``"l,t,r,b"`` (fractions when all <= 1)."""
    values = [float(v) for v in text.split(",")]
    if len(values) != 4:
        raise SystemExit(f"--box: expected LEFT,TOP,RIGHT,BOTTOM, got {text!r}")
    if all(v <= 1.0 for v in values):
        values = [values[0] * width, values[1] * height, values[2] * width, values[3] * height]
    left, top, right, bottom = (int(round(v)) for v in values)
    if not (0 <= left < right <= width and 0 <= top < bottom <= height):
        raise SystemExit(f"--box {text!r} is not inside the {width} x {height} image")
    return left, top, right, bottom


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("src", type=Path)
    ap.add_argument("dst", type=Path)
    ap.add_argument("--box", required=True, help="LEFT,TOP,RIGHT,BOTTOM")
    ap.add_argument("--min-px", type=int, default=50)
    args = ap.parse_args()
    if args.dst.exists():
        shutil.rmtree(args.dst)
    shutil.copytree(args.src / "input", args.dst / "input")
    if (args.src / "gt").is_dir():
        shutil.copytree(args.src / "gt", args.dst / "gt")
    inp = args.dst / "input"
    camera = json.loads((inp / "camera.json").read_text())
    left, top, right, bottom = crop_box(args.box, camera["width"], camera["height"])
    for name in ("rgb.png", "depth.png", "masks.png"):
        if (inp / name).is_file():
            image = np.asarray(Image.open(inp / name))
            Image.fromarray(np.ascontiguousarray(image[top:bottom, left:right])).save(inp / name)
    if (inp / "depth.npy").is_file():
        depth = np.load(inp / "depth.npy")
        np.save(inp / "depth.npy", np.ascontiguousarray(depth[top:bottom, left:right]))
    camera["width"], camera["height"] = right - left, bottom - top
    camera["K"][0][2] -= left
    camera["K"][1][2] -= top
    (inp / "camera.json").write_text(json.dumps(camera, indent=1))
    masks = np.asarray(Image.open(inp / "masks.png")).copy()
    ids, counts = np.unique(masks[masks > 0], return_counts=True)
    dropped = {int(i) for i, c in zip(ids, counts) if c < args.min_px}
    kept = {int(i) for i in ids} - dropped
    for i in dropped:
        masks[masks == i] = 0
    Image.fromarray(masks).save(inp / "masks.png")
    objects_path = inp / "objects.json"
    if objects_path.is_file():
        objects = json.loads(objects_path.read_text())
        objects["objects"] = [o for o in objects.get("objects", []) if int(o["id"]) in kept]
        objects_path.write_text(json.dumps(objects, indent=1))
    print(f"{args.dst}: {right - left} x {bottom - top} crop at ({left}, {top}); "
          f"instances kept {sorted(kept)}, dropped {sorted(dropped)}")


if __name__ == "__main__":
    main()
