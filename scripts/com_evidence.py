#!/usr/bin/env python
"""What a scene says about its objects' centres of mass (docs/diagnose.md, COM offset).

For each scene (after physopt): per object, how far physopt moved its COM from the shape's
centroid (across gravity / along it), and the 1 s rollout motion of the geomopt state and
of physopt's poses, with physopt's own COMs and with uniform density.

Usage:
  python scripts/com_evidence.py bench/diagnose/com_offset_s0 bench/diagnose/clean_s0
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.diagnose.measure.observe import physics_residual, world_spec  # noqa: E402
from r2s.diagnose.measure.scene_dir import export_options, load_objects  # noqa: E402
from r2s.io.input_scene import load_input  # noqa: E402
from r2s.io.mesh_io import load_mesh  # noqa: E402
from r2s.io.paths import ScenePaths  # noqa: E402
from r2s.io.state import read_state  # noqa: E402


def com_shifts(paths: ScenePaths) -> str:
    state = read_state(paths.stage_dir("physopt"))
    up = -np.asarray(state.gravity, dtype=np.float64)
    up /= np.linalg.norm(up)
    cells = []
    for obj in state.objects:
        centroid = load_mesh(paths.stage_dir("physopt") / obj.mesh).center_mass
        com = centroid if obj.com_in_object is None else np.asarray(obj.com_in_object)
        shift = np.asarray(obj.pose)[:3, :3] @ (com - centroid)
        along = float(shift @ up)
        across = float(np.linalg.norm(shift - along * up))
        cells.append(f"{obj.id}: {across * 1000:.1f} / {along * 1000:.1f}")
    return "physopt COM shift across / along gravity [mm]: " + ", ".join(cells)


def rollout(paths: ScenePaths, stage: str, uniform: bool) -> str:
    inp = load_input(paths.root)
    state = read_state(paths.stage_dir(stage))
    objects = load_objects(paths, stage, state, inp)
    if uniform:
        objects = [replace(o, com_in_object=None, friction=None, mass_kg=None) for o in objects]
    ex = export_options(paths)
    spec = world_spec(objects, state.support.point, state.support.normal, state.support.friction,
                      paths.convex_cache, ex.density_kg_m3, ex.default_friction, ex.convex)
    phys = physics_residual(spec, np.asarray(state.gravity), {o.id: True for o in objects}, 1.0,
                            0.015, float(np.radians(5.0)), 4.0)
    cells = [f"{i}: {m.translation_norm_m * 1000:.0f} mm / {np.degrees(m.angle_rad):.0f} deg"
             for i, m in phys.motion.items()]
    what = f"{stage}, {'uniform density' if uniform else 'its own COMs'}"
    return f"1 s rollout of {what}: " + ", ".join(cells)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("scenes", nargs="+", type=Path)
    args = ap.parse_args()
    for scene in args.scenes:
        paths = ScenePaths(scene)
        print(f"{scene.name}")
        print("  " + com_shifts(paths))
        for stage, uniform in (("geomopt", True), ("physopt", False), ("physopt", True)):
            print("  " + rollout(paths, stage, uniform), flush=True)


if __name__ == "__main__":
    main()
