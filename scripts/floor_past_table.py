"""Derive a scene whose table ends behind the objects, with the floor seen past its edge.

The benchmark's synthetic tables are 3 m wide, so the camera never sees past them; a real
capture often does (the floor, a lower shelf). This copies ``SRC``'s ``input/`` and ``gt/``
to ``DST`` and, for every background pixel (mask 0) whose ray meets the table farther than
``--edge-m`` beyond the objects' centre (along the camera's horizontal viewing direction),
replaces the depth with where the ray meets a floor ``--floor-m`` below the table, with
noise that grows with depth squared (``--noise``, sigma = noise * z^2 metres) and no
reading past ``--max-range-m``. Masks, RGB and gt/ are unchanged (the floor is background;
the RGB still shows the table, which no stage reads as geometry).

Usage::

    python scripts/floor_past_table.py bench/s_A/scene_00_noprior /tmp/floor_scene \\
        --edge-m 0.12 --floor-m 0.3
    r2s run /tmp/floor_scene --skip texture

Assumes the scene's table is the plane z = 0 of gt/ (the synthetic scenes' support).
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
from PIL import Image


def floor_depth(depth_m: np.ndarray, masks: np.ndarray, K: np.ndarray,
                world_from_camera: np.ndarray, centre_xy: np.ndarray, edge_m: float,
                floor_m: float, noise: float, max_range_m: float, seed: int
                ) -> tuple[np.ndarray, int]:
    """(H, W) the depth with the floor past the edge, and how many pixels were replaced."""
    height, width = depth_m.shape
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    rays_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1],
                         np.ones_like(u)], axis=-1)           # z = 1: t along a ray is depth
    rays = rays_cam @ world_from_camera[:3, :3].T
    centre = world_from_camera[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_table = -centre[2] / rays[..., 2]
        t_floor = (-floor_m - centre[2]) / rays[..., 2]
    on_table = centre + t_table[..., None] * rays
    forward = rays[height // 2, width // 2].copy()
    forward[2] = 0.0
    forward /= np.linalg.norm(forward)
    beyond = ((on_table[..., :2] - centre_xy) @ forward[:2] > edge_m) | ~(t_table > 0)
    replace = beyond & (np.asarray(masks) == 0) & (t_floor > 0)
    rng = np.random.default_rng(seed)
    z = t_floor + rng.normal(0.0, 1.0, t_floor.shape) * noise * np.nan_to_num(t_floor) ** 2
    out = np.asarray(depth_m, dtype=np.float64).copy()
    out[replace] = np.where(t_floor[replace] < max_range_m, z[replace], 0.0)
    return out, int(replace.sum())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("src", type=Path)
    ap.add_argument("dst", type=Path)
    ap.add_argument("--edge-m", type=float, default=0.15,
                    help="the table's far edge, beyond the objects' centre (m)")
    ap.add_argument("--floor-m", type=float, default=0.75, help="floor below the table (m)")
    ap.add_argument("--noise", type=float, default=0.0015, help="sigma = noise * z^2 (m)")
    ap.add_argument("--max-range-m", type=float, default=4.0)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if args.dst.exists():
        shutil.rmtree(args.dst)
    shutil.copytree(args.src / "input", args.dst / "input")
    shutil.copytree(args.src / "gt", args.dst / "gt")
    cam = json.loads((args.dst / "input" / "camera.json").read_text())
    unit = float(cam.get("depth_unit_m", 0.001))
    depth_path = args.dst / "input" / "depth.png"
    depth = np.asarray(Image.open(depth_path), dtype=np.float64) * unit
    masks = np.asarray(Image.open(args.dst / "input" / "masks.png"))
    gt = json.loads((args.dst / "gt" / "scene.json").read_text())
    centre = np.mean([np.asarray(o["world_from_object"])[:2, 3] for o in gt["objects"]], axis=0)
    out, replaced = floor_depth(depth, masks, np.asarray(cam["K"]),
                                np.asarray(cam["world_from_camera"]), centre, args.edge_m,
                                args.floor_m, args.noise, args.max_range_m, args.seed)
    Image.fromarray(np.clip(np.round(out / unit), 0, 65535).astype(np.uint16)).save(depth_path)
    print(f"{args.dst}: {replaced} of {int((masks == 0).sum())} background pixels now see the "
          f"floor {args.floor_m} m below the table")


if __name__ == "__main__":
    main()
