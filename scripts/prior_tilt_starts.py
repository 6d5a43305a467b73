#!/usr/bin/env python
"""Would more registration starts fix a prior's pose? (synthetic scenes, reads gt/)

For each scene whose init ran with ``--set prior_choice=prior``, registers every prior again
as init does (r2s.stages.init's registration options, free-space term) from the given pose
and from that pose tilted by +-TILT degrees about two horizontal axes through the observed
centroid (4 more starts), scores each result against the view with the other objects as
init left them (r2s/geometry/prior_choice.py) and keeps the start with the highest
``IoU - free space``. Prints, per object, the given start's and the kept start's scores
(IoU / UCD mm / free space) and CD against gt (mm).

Usage:
  python scripts/prior_tilt_starts.py SCENE [SCENE ...] [--tilt-deg 15]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.geometry.free_space import view_constraint  # noqa: E402
from r2s.geometry.prior_choice import score_in_view  # noqa: E402
from r2s.geometry.registration import register_prior, voxel_downsample  # noqa: E402
from r2s.io.input_scene import load_input  # noqa: E402
from r2s.io.manifest import load_manifest  # noqa: E402
from r2s.io.mesh_io import load_mesh  # noqa: E402
from r2s.io.paths import ScenePaths  # noqa: E402
from r2s.io.scene_json import read_gt_scene  # noqa: E402
from r2s.io.state import read_state  # noqa: E402
from r2s.metrics.geometry import chamfer_distance_mm, posed  # noqa: E402
from r2s.scene_model import corrected_input  # noqa: E402
from r2s.stages.init import Options, _icp_options  # noqa: E402


def _tilted(world_from_prior: np.ndarray, pivot: np.ndarray, up: np.ndarray,
            tilt_deg: float) -> list[np.ndarray]:
    """The given pose, then turned by +-tilt about two horizontal axes through ``pivot``."""
    side = np.cross(up, [1.0, 0.0, 0.0])
    if np.linalg.norm(side) < 0.1:
        side = np.cross(up, [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)
    out = [world_from_prior]
    for axis in (side, np.cross(up, side)):
        for sign in (1.0, -1.0):
            turn = np.eye(4)
            turn[:3, :3] = Rotation.from_rotvec(axis * np.radians(sign * tilt_deg)).as_matrix()
            turn[:3, 3] = pivot - turn[:3, :3] @ pivot
            out.append(turn @ world_from_prior)
    return out


def _scene_rows(root: Path, tilt_deg: float) -> list[str]:
    paths = ScenePaths(root)
    view = corrected_input(load_input(root), load_manifest(paths.manifest).model)
    cam = view.camera
    state = read_state(paths.stage_dir("init"))
    gt = {g.id: g for g in read_gt_scene(paths.gt_scene).objects}
    meshes = {o.id: posed(load_mesh(paths.stage_dir("init") / o.mesh), np.asarray(o.pose))
              for o in state.objects}
    specs = {s.id: s for s in view.objects}
    up = np.asarray(state.support.normal, dtype=np.float64)
    rows = []
    for o in state.objects:
        spec = specs.get(o.id)
        if spec is None or spec.prior_mesh is None or o.id not in gt:
            continue
        prior = load_mesh(spec.prior_mesh)
        truth = posed(load_mesh(paths.gt / gt[o.id].mesh), np.asarray(gt[o.id].world_from_object))
        pts = np.load(paths.stage_dir("init") / o.observed_points).astype(np.float64)
        constraint = view_constraint(cam.K, cam.world_from_camera, view.depth_m,
                                     view.masks == o.id)
        others = [(j, m) for j, m in meshes.items() if j != o.id]
        results = []
        for start in _tilted(np.asarray(spec.world_from_prior), pts.mean(axis=0), up, tilt_deg):
            reg = register_prior(prior, voxel_downsample(pts, 0.002), start, view=constraint,
                                 up=up, options=_icp_options(Options()))
            mesh = prior.copy()
            mesh.apply_scale(reg.scale)
            mesh.apply_transform(reg.world_from_object)
            s = score_in_view(mesh, o.id, others, pts, cam.K, cam.world_from_camera,
                              view.depth_m, view.masks)
            results.append((s, chamfer_distance_mm(mesh, truth)))
        kept = max(range(len(results)), key=lambda k: results[k][0].iou - results[k][0].free_space)
        fmt = [f"{s.iou:.2f} / {s.ucd_mm:.1f} / {s.free_space:.3f} / {cd:.1f}"
               for s, cd in (results[0], results[kept])]
        rows.append(f"| {root.name} | {o.id} | {fmt[0]} | {fmt[1]} | {kept} |")
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="+", type=Path)
    parser.add_argument("--tilt-deg", type=float, default=15.0)
    args = parser.parse_args()
    print("| scene | id | given start IoU / UCD / free / CD | best of 5 starts | start kept |")
    print("|---|---:|---|---|---:|")
    for root in args.scenes:
        for row in _scene_rows(root, args.tilt_deg):
            print(row, flush=True)


if __name__ == "__main__":
    main()
