"""How long PyBullet takes a step of an exported scene, as its pieces are, or simplified.

Builds the bodies of ``EXPORT/scene.json`` (its collision pieces, masses and COMs) on a
plane in a fresh PyBullet world, lets them fall for ``--steps`` steps of 1/240 s, and
prints the wall time and where each body ends. ``--cap N`` rebuilds every piece with more
than N vertices as the hull of N of them (:func:`r2s.geometry.collision_trim.capped_hull`:
inside the piece); ``--one-hull`` gives each body the single hull of its pieces (another
physics: a measure of how much the pieces' number costs). Each variant is timed
``--repeats`` times; the median is printed.

Usage:
  python scripts/piece_step_time.py SCENE/export
  python scripts/piece_step_time.py SCENE/export --cap 32
  python scripts/piece_step_time.py SCENE/export --one-hull
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pybullet as pb
import trimesh
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from r2s.geometry.collision_trim import capped_hull  # noqa: E402


def piece_files(export: Path, obj: dict, cap: int, one_hull: bool, tmp: Path) -> list[str]:
    """The files of one object's pieces as the variant builds them."""
    files = [export / f for f in obj["collision_meshes"]]
    if not cap and not one_hull:
        return [str(f) for f in files]
    pieces = [trimesh.load(f, force="mesh") for f in files]
    if one_hull:
        pieces = [trimesh.util.concatenate(pieces).convex_hull]
    out = []
    for k, piece in enumerate(pieces):
        if cap and len(piece.vertices) > cap:
            piece = capped_hull(np.asarray(piece.vertices), cap)
        path = tmp / f"{obj['id']}_{k}.obj"
        piece.export(path)
        out.append(str(path))
    return out


def run_once(export: Path, scene: dict, cap: int, one_hull: bool, steps: int
             ) -> tuple[float, int, dict[int, np.ndarray]]:
    """(seconds for ``steps`` steps, pieces, id -> final base position)."""
    client = pb.connect(pb.DIRECT)
    try:
        pb.setGravity(0, 0, -9.81, physicsClientId=client)
        plane = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=client)
        pb.createMultiBody(0, plane, physicsClientId=client)
        bodies, count = {}, 0
        with tempfile.TemporaryDirectory() as tmp:
            for obj in scene["objects"]:
                files = piece_files(export, obj, cap, one_hull, Path(tmp))
                count += len(files)
                shape = pb.createCollisionShapeArray([pb.GEOM_MESH] * len(files),
                                                     fileNames=files, physicsClientId=client)
                pose = np.asarray(obj["world_from_object"])
                bodies[obj["id"]] = pb.createMultiBody(
                    obj["mass_kg"], shape, basePosition=pose[:3, 3].tolist(),
                    baseOrientation=Rotation.from_matrix(pose[:3, :3]).as_quat().tolist(),
                    baseInertialFramePosition=obj["com_in_object"], physicsClientId=client)
        start = time.perf_counter()
        for _ in range(steps):
            pb.stepSimulation(physicsClientId=client)
        seconds = time.perf_counter() - start
        ends = {i: np.asarray(pb.getBasePositionAndOrientation(b, physicsClientId=client)[0])
                for i, b in bodies.items()}
        return seconds, count, ends
    finally:
        pb.disconnect(client)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("export", type=Path)
    ap.add_argument("--cap", type=int, default=0, help="most vertices of a piece (0: as is)")
    ap.add_argument("--one-hull", action="store_true")
    ap.add_argument("--steps", type=int, default=1200)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    scene = json.loads((args.export / "scene.json").read_text())
    runs = [run_once(args.export, scene, args.cap, args.one_hull, args.steps)
            for _ in range(args.repeats)]
    seconds = statistics.median(r[0] for r in runs)
    print(f"pieces {runs[0][1]}; {args.steps} steps: median {seconds:.2f} s "
          f"over {args.repeats} runs ({1000 * seconds / args.steps:.2f} ms a step)")
    for i, p in sorted(runs[0][2].items()):
        print(f"  object {i} ends at z {1000 * p[2]:.1f} mm")


if __name__ == "__main__":
    main()
