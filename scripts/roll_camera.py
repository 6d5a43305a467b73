#!/usr/bin/env python
"""Copy a scene as seen by its camera rolled by quarter turns about its line of sight.

The images are turned exactly (``numpy.rot90``: no resampling) and ``camera.json`` gets the
matching intrinsics and ``world_from_camera``, so every pixel back-projects to the same
world point as before: the copy is the same capture from a camera held on its side (one
quarter turn) or upside down (two). A reconstruction of the copy should match the
original's up to the pixel grid; what differs measures what r2s assumes about the
image's up direction. ``input/`` and ``gt/`` are copied (gt/ as it is: it is in the world
frame); nothing else.

One quarter turn counter-clockwise maps the pixel (u, v) of a W x H image to
(v, W - 1 - u): in camera coordinates (x', y', z') = (y, -x, z), so fx' = fy, fy' = fx,
cx' = cy, cy' = W - 1 - cx, and ``world_from_camera' = world_from_camera @ T`` where T
takes the turned coordinates back (x = -y', y = x', z = z').

Usage:
  python scripts/roll_camera.py SRC DST --quarter-turns 1
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
from PIL import Image

IMAGES = ("rgb.png", "depth.png", "masks.png")


def quarter_turn(K: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
    """(K', camera_from_turned (4, 4)) of one counter-clockwise quarter turn of a
    ``width``-pixel-wide image with intrinsics ``K`` (3, 3)."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    turned_K = np.array([[fy, 0.0, cy], [0.0, fx, width - 1 - cx], [0.0, 0.0, 1.0]])
    camera_from_turned = np.eye(4)
    camera_from_turned[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    return turned_K, camera_from_turned


def rolled_camera(camera: dict, turns: int) -> dict:
    """camera.json's dict for the image turned ``turns`` quarter turns counter-clockwise."""
    K = np.asarray(camera["K"], dtype=np.float64)
    pose = np.asarray(camera["world_from_camera"], dtype=np.float64)
    width, height = int(camera["width"]), int(camera["height"])
    for _ in range(turns % 4):
        K, camera_from_turned = quarter_turn(K, width)
        pose = pose @ camera_from_turned
        width, height = height, width
    return {**camera, "K": K.tolist(), "world_from_camera": pose.tolist(), "width": width,
            "height": height}


def roll_scene(src: Path, dst: Path, turns: int) -> None:
    """Write the rolled copy of scene ``src`` to ``dst`` (which must not exist)."""
    if dst.exists():
        raise SystemExit(f"{dst} exists: give a new folder")
    if not (src / "input" / "camera.json").is_file():
        raise SystemExit(f"{src / 'input' / 'camera.json'}: not found (SRC must be a scene)")
    shutil.copytree(src / "input", dst / "input")
    if (src / "gt").is_dir():
        shutil.copytree(src / "gt", dst / "gt")
    camera = json.loads((src / "input" / "camera.json").read_text())
    (dst / "input" / "camera.json").write_text(json.dumps(rolled_camera(camera, turns),
                                                          indent=1))
    for name in IMAGES:
        path = src / "input" / name
        if path.is_file():
            with Image.open(path) as image:
                pixels = np.asarray(image)
            Image.fromarray(np.ascontiguousarray(np.rot90(pixels, turns))).save(
                dst / "input" / name)
    npy = src / "input" / "depth.npy"
    if npy.is_file():
        np.save(dst / "input" / "depth.npy", np.ascontiguousarray(np.rot90(np.load(npy), turns)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("src", type=Path)
    ap.add_argument("dst", type=Path)
    ap.add_argument("--quarter-turns", type=int, default=1,
                    help="counter-clockwise quarter turns of the image (1, 2 or 3)")
    args = ap.parse_args()
    roll_scene(args.src, args.dst, args.quarter_turns)
    print(f"{args.dst}: the camera rolled by {90 * (args.quarter_turns % 4)} deg")


if __name__ == "__main__":
    main()
