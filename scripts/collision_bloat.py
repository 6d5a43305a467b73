#!/usr/bin/env python
"""How much larger than the visual meshes are the convex collision pieces of a state?

For each object of STAGE's state (default geomopt): the volume of the union of its convex
pieces (r2s/geometry/convex.py, the default decomposition; with --trimmed, as physopt
trims them by default: the completed objects' pieces against the neighbours at these
poses, r2s/geometry/collision_trim.py) over its
mesh's volume (union: 200k deterministic random points in the pieces' box), its mesh's
volume over its convex hull's, and how deep (mm) the visual mesh of each other object
reaches into its pieces (4000 seeded surface samples; listed when over 2 mm; physopt
does not trim against the samples that lie inside the object's own mesh).

With --overlaps: every pair of objects whose pieces Bullet finds overlapping by more
than 1.5 mm (r2s/physopt/piece_overlap.py; its margins, about 1 mm per hull, included),
the deepest such overlap, and how deep the two visual meshes reach into each other
(physopt cuts the pieces only where that is at most 1.5 mm).

Usage:
  python scripts/collision_bloat.py SCENE [--stage geomopt] [--trimmed] [--overlaps]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.geometry.collision_trim import inside_depth_m, surface_points, trim_scene_pieces  # noqa: E402
from r2s.geometry.convex import convex_decomposition  # noqa: E402
from r2s.io.mesh_io import load_mesh, welded  # noqa: E402
from r2s.io.state import read_state  # noqa: E402
from r2s.physopt.piece_overlap import piece_overlaps, visual_penetration_m  # noqa: E402


def union_volume_m3(pieces: list, samples: int = 200_000) -> float:
    """Monte Carlo volume of the union of convex pieces (fixed seed)."""
    lo = np.min([p.bounds[0] for p in pieces], axis=0)
    hi = np.max([p.bounds[1] for p in pieces], axis=0)
    pts = np.random.default_rng(0).uniform(lo, hi, size=(samples, 3))
    inside = np.zeros(samples, dtype=bool)
    for p in pieces:
        inside |= inside_depth_m(p, pts) >= 0
    return float(inside.mean() * np.prod(hi - lo))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", type=Path)
    ap.add_argument("--stage", default="geomopt")
    ap.add_argument("--trimmed", action="store_true",
                    help="trim the pieces against the neighbours as physopt does")
    ap.add_argument("--overlaps", action="store_true",
                    help="the piece pairs Bullet finds overlapping, and the visual meshes' "
                         "own interpenetration")
    args = ap.parse_args()
    state = read_state(args.scene / args.stage)
    meshes = {o.id: welded(load_mesh(args.scene / args.stage / o.mesh)) for o in state.objects}
    poses = {o.id: np.asarray(o.pose) for o in state.objects}
    pieces = {i: convex_decomposition(m) for i, m in meshes.items()}
    if args.trimmed:  # physopt's default (trim_collision=completed): completed objects only
        pieces, _ = trim_scene_pieces(pieces, meshes, poses,
                                      only={o.id for o in state.objects
                                            if o.source == "completed"})
    for a, mesh in meshes.items():
        ratio = union_volume_m3(pieces[a]) / mesh.volume
        line = (f"object {a}: {len(pieces[a])} pieces, pieces/mesh volume {ratio:.2f}, "
                f"mesh/hull {mesh.volume / mesh.convex_hull.volume:.2f}")
        object_from_world = np.linalg.inv(poses[a])
        for b, other in meshes.items():
            if b == a:
                continue
            pts = surface_points(other.copy().apply_transform(object_from_world @ poses[b]),
                                 4000, seed=b)
            depth = max(float(inside_depth_m(p, pts).max()) for p in pieces[a])
            if depth > 0.002:
                line += f"; object {b} reaches {1000 * depth:.1f} mm into its pieces"
        print(line)
    if args.overlaps:
        print_overlaps(pieces, meshes, poses)


def print_overlaps(pieces: dict, meshes: dict, poses: dict) -> None:
    """Per object pair: the deepest Bullet overlap of their pieces and the visual meshes'
    interpenetration (mm)."""
    deepest: dict[tuple[int, int], float] = {}
    for o in piece_overlaps(pieces, poses):
        pair = (min(o.a[0], o.b[0]), max(o.a[0], o.b[0]))
        deepest[pair] = max(deepest.get(pair, 0.0), o.depth_m)
    for (i, j), depth in sorted(deepest.items()):
        visual = visual_penetration_m(meshes, poses, i, j)
        print(f"objects {i} and {j}: pieces overlap {1000 * depth:.1f} mm (Bullet), visual "
              f"meshes {1000 * visual:.1f} mm into each other")


if __name__ == "__main__":
    main()
