#!/usr/bin/env python
"""How much larger than the visual meshes are the convex collision pieces of a state?

For each object of STAGE's state (default geomopt): the volume of its convex pieces
(r2s/geometry/convex.py, the default decomposition) over its mesh's volume, its mesh's
volume over its convex hull's, and how deep (mm) the visual mesh of each other object
reaches into its pieces (4000 surface samples; listed when over 2 mm).

Usage:
  python scripts/collision_bloat.py SCENE [--stage geomopt]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import trimesh

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.geometry.convex import convex_decomposition  # noqa: E402
from r2s.io.mesh_io import load_mesh  # noqa: E402
from r2s.io.state import read_state  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", type=Path)
    ap.add_argument("--stage", default="geomopt")
    args = ap.parse_args()
    state = read_state(args.scene / args.stage)
    meshes = {o.id: (load_mesh(args.scene / args.stage / o.mesh), np.asarray(o.pose))
              for o in state.objects}
    for a, (mesh, pose) in meshes.items():
        pieces = convex_decomposition(mesh)
        ratio = sum(p.volume for p in pieces) / mesh.volume
        line = (f"object {a}: {len(pieces)} pieces, pieces/mesh volume {ratio:.2f}, "
                f"mesh/hull {mesh.volume / mesh.convex_hull.volume:.2f}")
        object_from_world = np.linalg.inv(pose)
        for b, (other, other_pose) in meshes.items():
            if b == a:
                continue
            pts = other.copy().apply_transform(object_from_world @ other_pose).sample(4000)
            depth = max(float(trimesh.proximity.signed_distance(p, pts).max()) for p in pieces)
            if depth > 0.002:
                line += f"; object {b} reaches {1000 * depth:.1f} mm into its pieces"
        print(line)


if __name__ == "__main__":
    main()
