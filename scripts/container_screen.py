"""Which completed objects of some scenes are open containers, and what their walls weigh.

For every object that init completed (``init/state.json``, source ``completed``) of each
SCENE given, print its label, whether :func:`r2s.geometry.open_container.open_container`
finds it a container, the solid's volume, and for a container the walls' mass and how far
the centroid of its outside faces (where the walls' mass is) lies from the solid's
centroid: in height, as a share of the shape's height, and sideways (mm). With gt/, the
object's true mass and how upright it stands (the z component of its gt z axis: 1 open
side up, -1 upside down, 0 on its side).

Usage:
  python scripts/container_screen.py bench/containers/scene_* bench/fresh10/scene_0*
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from r2s.geometry.open_container import UP_NZ, open_container  # noqa: E402
from r2s.geometry.sdf import first_hit_distance, raycasting_scene  # noqa: E402


def outside_centroid(mesh: trimesh.Trimesh) -> np.ndarray:
    """(3,) area-weighted centroid of the faces :func:`outside_area_m2` counts."""
    normals = np.asarray(mesh.face_normals)
    faces = np.flatnonzero(normals[:, 2] <= UP_NZ)
    centres = np.asarray(mesh.triangles_center)[faces]
    dist = first_hit_distance(raycasting_scene(mesh.vertices, mesh.faces),
                              centres + 1e-4 * normals[faces], normals[faces])
    out = ~np.isfinite(dist)
    area = np.asarray(mesh.area_faces)[faces][out]
    return (centres[out] * area[:, None]).sum(axis=0) / area.sum()


def rows(scene: Path) -> list[str]:
    state_file = scene / "init" / "state.json"
    if not state_file.is_file():
        return []
    gt_file = scene / "gt" / "scene.json"
    gt = ({o["id"]: o for o in json.loads(gt_file.read_text())["objects"]}
          if gt_file.is_file() else {})
    out = []
    for o in json.loads(state_file.read_text())["objects"]:
        if o.get("source") != "completed":
            continue
        mesh = trimesh.load(scene / "init" / o["mesh"], force="mesh")
        found = open_container(mesh)
        truth = gt.get(o["id"], {})
        upright = (f"{np.asarray(truth['world_from_object'])[2, 2]:.2f}"
                   if "world_from_object" in truth else "-")
        mass = f"{truth['mass_kg']:.3f}" if "mass_kg" in truth else "-"
        cells = [scene.name, str(o["id"]), truth.get("label", o.get("label") or "-"),
                 upright, mass, f"{1e6 * abs(mesh.volume):.0f}"]
        if found is None:
            cells += ["no", "-", "-", "-"]
        else:
            height = mesh.bounds[1][2] - mesh.bounds[0][2]
            shift = outside_centroid(mesh) - np.asarray(mesh.center_mass)
            cells += ["yes", f"{found.walls_mass_kg():.3f}", f"{shift[2] / height:+.2f}",
                      f"{1000 * np.linalg.norm(shift[:2]):.1f}"]
        out.append("| " + " | ".join(cells) + " |")
    return out


def main() -> None:
    print("| scene | id | label | gt upright | gt mass [kg] | solid [cm^3] | container | "
          "walls [kg] | walls' centroid - solid's, height share | sideways [mm] |")
    print("|---|---:|---|---:|---:|---:|---|---:|---:|---:|")
    found = total = 0
    for arg in sys.argv[1:]:
        for line in rows(Path(arg)):
            total += 1
            found += "| yes |" in line
            print(line)
    print(f"\n{found} of {total} completed objects are open containers")


if __name__ == "__main__":
    main()
