"""Time the graph and geomopt stages on a synthetic 10-object tabletop.

    python scripts/bench_geomopt.py [--resolution 128] [--voxel 0.0015 | --voxel 0] [--keep DIR]

The scene (boxes, a plate on two blocks, a cylinder on the plate, a box on a box, a sphere,
a board leaning on a block) is perturbed with seeded noise (sinking, floating, small
tilts) and written as an ``init/`` state; the script then runs ``graph`` and ``geomopt``
and prints their times and the contact state before and after.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
import trimesh
from scipy.spatial.transform import Rotation

from r2s.io.paths import ScenePaths
from r2s.io.state import ObjectState, SceneState, SupportPlane, write_state
from r2s.stages import geomopt, graph
from r2s.runner.base import run_stage
from r2s.io.manifest import StageRecord, load_manifest, save_manifest


def _pose(centre, rotation=None) -> np.ndarray:
    out = np.eye(4)
    if rotation is not None:
        out[:3, :3] = rotation
    out[:3, 3] = centre
    return out


def synthetic_scene(seed: int = 0) -> list[tuple[int, str, trimesh.Trimesh, np.ndarray]]:
    """Ten objects resting exactly, then perturbed by up to 6 mm and 2 degrees."""
    th = np.radians(20.0)
    cz = 0.01 * np.sin(th) + 0.06 * np.cos(th)
    zc = (0.10 - cz + 0.01 * np.sin(th)) / np.cos(th)
    cx = 0.03 + 0.01 * np.cos(th) + zc * np.sin(th)
    lean = np.array([[np.cos(-th), 0, np.sin(-th)], [0, 1, 0], [-np.sin(-th), 0, np.cos(-th)]])
    objs = [
        (1, "block_a", trimesh.creation.box((0.04, 0.06, 0.05)), _pose((-0.08, 0.0, 0.025))),
        (2, "block_b", trimesh.creation.box((0.04, 0.06, 0.05)), _pose((0.08, 0.0, 0.025))),
        (3, "plate", trimesh.creation.box((0.25, 0.08, 0.01)), _pose((0.0, 0.0, 0.055))),
        (4, "can", trimesh.creation.cylinder(radius=0.03, height=0.08, sections=48),
         _pose((0.0, 0.0, 0.06 + 0.04))),
        (5, "big_box", trimesh.creation.box((0.10, 0.10, 0.05)), _pose((0.0, 0.18, 0.025))),
        (6, "small_box", trimesh.creation.box((0.05, 0.05, 0.04)), _pose((0.01, 0.18, 0.07))),
        (7, "ball", trimesh.creation.icosphere(subdivisions=3, radius=0.035),
         _pose((-0.15, 0.15, 0.035))),
        (8, "block_c", trimesh.creation.box((0.06, 0.06, 0.10)), _pose((0.0, -0.2, 0.05))),
        (9, "board", trimesh.creation.box((0.02, 0.06, 0.12)), _pose((cx, -0.2, cz), lean)),
        (10, "neighbour", trimesh.creation.box((0.05, 0.05, 0.06)), _pose((0.15 + 0.0255, 0.15, 0.03))),
    ]
    rng = np.random.default_rng(seed)
    out = []
    for obj_id, label, mesh, pose in objs:
        noise = np.eye(4)
        noise[:3, :3] = Rotation.from_rotvec(rng.normal(size=3) * np.radians(1.0)).as_matrix()
        noise[:3, 3] = [rng.uniform(-2e-3, 2e-3), rng.uniform(-2e-3, 2e-3), rng.uniform(-6e-3, 6e-3)]
        centre = pose[:3, 3].copy()
        perturbed = pose.copy()
        perturbed[:3, :3] = noise[:3, :3] @ pose[:3, :3]
        perturbed[:3, 3] = centre + noise[:3, 3]
        out.append((obj_id, label, mesh, perturbed))
    return out


def write_scene(root: Path, seed: int = 0) -> Path:
    paths = ScenePaths(root)
    init = paths.stage_dir("init")
    (init / "meshes").mkdir(parents=True, exist_ok=True)
    states = []
    for obj_id, label, mesh, pose in synthetic_scene(seed):
        (init / "meshes" / f"{obj_id}.glb").write_bytes(mesh.export(file_type="glb"))
        states.append(ObjectState(id=obj_id, label=label, mesh=f"meshes/{obj_id}.glb",
                                  world_from_object=pose.tolist()))
    write_state(init, SceneState(stage="init", support=SupportPlane(point=[0, 0, 0], normal=[0, 0, 1]),
                                 objects=states))
    manifest = load_manifest(paths.manifest)
    manifest.stages["init"] = StageRecord(status="done")
    save_manifest(paths.manifest, manifest)
    return root


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=128, help="SDF voxels per axis")
    parser.add_argument("--voxel", type=float, default=0.0015,
                        help="sdf_voxel_size_m (m), resolution as the cap; 0: fixed resolution")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    parser.add_argument("--keep", type=Path, default=None, help="write the scene here and keep it")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    root = args.keep or Path(tempfile.mkdtemp(prefix="r2s-bench-geomopt-"))
    if root.exists() and args.keep:
        shutil.rmtree(root)
    try:
        write_scene(root / "scene" if not args.keep else root)
        scene = root / "scene" if not args.keep else root
        t = time.perf_counter()
        g = run_stage(graph.STAGE, scene)
        t_graph = time.perf_counter() - t
        t = time.perf_counter()
        r = run_stage(geomopt.STAGE, scene, geomopt.Options(sdf_resolution=args.resolution,
                                                           sdf_voxel_size_m=args.voxel or None))
        t_geom = time.perf_counter() - t
        s = r.summary
        print(f"objects: {s['objects']}  torch threads: {torch.get_num_threads()}  "
              f"SDF resolution: {args.resolution}, voxel: {args.voxel}")
        print(f"graph stage:   {t_graph:6.2f} s  ({g.summary})")
        print(f"geomopt stage: {t_geom:6.2f} s  (SDFs {s['sdf_seconds']:.2f} s, optimisation "
              f"{s['optimise_seconds']:.2f} s, {s['iterations']} iterations, "
              f"converged={s['converged']})")
        for key in ("max_penetration_pairs_mm", "max_penetration_table_mm", "max_support_gap_mm"):
            print(f"  {key:28s} before {s['before_' + key]:8.3f}   after {s['after_' + key]:8.3f}")
        print(f"  largest move: {s['max_translation_mm']:.2f} mm, {s['max_rotation_deg']:.2f} deg")
    finally:
        if not args.keep:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
