"""Where each exported physical parameter came from (``provenance`` in export/scene.json).

Per object::

    "provenance": {
      "mass":     {"source": "user"} | {"source": "user_density", "density_kg_m3": ..}
                  | {"source": "density_table", "category": "box", "density_kg_m3": ..,
                     "ref": ".."} | {"source": "default_density", "density_kg_m3": ..}
                  | {"source": "open_container", "outside_area_cm2": .., "areal_density_kg_m2":
                     .., "solid": {the density's record}, ...} | {"source": "gt"},
      "friction": {"source": "user" | "default" | "optimised" | "at_bound" | "fitted_push"
                   | "gt", "value": .., ...},
      "com":      {"source": "mesh_centroid" | "repaired" | "fitted_push" | "gt",
                   "shift_m": |com - uniform-density centroid|}
    }
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from r2s.io.input_scene import ObjectEntry, load_objects
from r2s.io.paths import ScenePaths
from r2s.physical.density_table import DEFAULT_DENSITY_KG_M3, density_for_label

FORCED_REF = "stage option density_kg_m3"
"""The ``ref`` of a mass whose density the stage option forced."""

COM_SHIFT_TOL_M = 1e-4
"""A COM closer than this to the uniform-density centroid counts as the centroid."""


def user_entries(scene_root: Path) -> dict[int, ObjectEntry]:
    """``input/objects.json`` entries by id (empty when the file is absent)."""
    return load_objects(ScenePaths(Path(scene_root)))


def nominal_mass(label: str, volume_m3: float, user: Optional[ObjectEntry] = None,
                 density_kg_m3: Optional[float] = None) -> tuple[float, dict]:
    """Mass (kg) before any optimisation, and its provenance.

    Order: the user's ``mass_kg``; the user's ``density_kg_m3`` x volume; a density forced
    by the stage option ``density_kg_m3``; the label's density table entry; the default.
    """
    if user is not None and user.mass_kg is not None:
        return float(user.mass_kg), {"source": "user", "mass_kg": float(user.mass_kg)}
    if user is not None and user.density_kg_m3 is not None:
        rho = float(user.density_kg_m3)
        return rho * volume_m3, {"source": "user_density", "density_kg_m3": rho}
    if density_kg_m3 is not None:
        rho = float(density_kg_m3)
        return rho * volume_m3, {"source": "default_density", "density_kg_m3": rho,
                                 "ref": FORCED_REF}
    choice = density_for_label(label, DEFAULT_DENSITY_KG_M3)
    return choice.density_kg_m3 * volume_m3, choice.provenance()


TABLE_OR_DEFAULT = ("density_table", "default_density")
"""Mass provenances from the label's density or the default, not from the user or a forced
density (which reads ``default_density`` too, with ``ref`` :data:`FORCED_REF`): the ones a
container's walls replace."""


def container_mass(find_container, nominal_kg: float, provenance: dict
                   ) -> tuple[float, dict]:
    """(mass kg, provenance) of a completed shape whose mass ``nominal_kg`` came from a
    density (``provenance`` from :func:`nominal_mass`): the walls' mass when the shape is an
    open container (the completion is solid under the dip it saw, and volume x density
    weighs the space the container holds) and they weigh less than ``nominal_kg``.
    ``find_container()`` gives the shape's
    :class:`r2s.geometry.open_container.OpenContainer` or None; it is called only when the
    mass came from the label's density or the default. A user's mass or density, a
    density forced by a stage option, and a shape that is no container keep
    ``nominal_kg`` and ``provenance``."""
    if provenance.get("source") not in TABLE_OR_DEFAULT or provenance.get("ref") == FORCED_REF:
        return nominal_kg, provenance
    found = find_container()
    if found is None or found.walls_mass_kg() >= nominal_kg:
        return nominal_kg, provenance
    return found.walls_mass_kg(), {"source": "open_container", **found.as_dict(),
                                   "solid_mass_kg": round(float(nominal_kg), 4),
                                   "solid": provenance}


def friction_provenance(value: float, *, user: Optional[float] = None,
                        initial: Optional[float] = None,
                        bounds: Optional[tuple[float, float]] = None,
                        raised_for_stability: bool = False) -> dict:
    """Friction's provenance: user-given, left at its initial (default) value, at a bound of
    the optimiser's range, or moved inside it (optimised)."""
    value = float(value)
    if user is not None and abs(value - user) < 1e-9:
        return {"source": "user", "value": value}
    out: dict = {"value": value}
    if bounds is not None and min(abs(value - bounds[0]), abs(value - bounds[1])) < 1e-9:
        out.update(source="at_bound", bounds=[float(bounds[0]), float(bounds[1])])
        if raised_for_stability:
            out["reason"] = "raised to the upper bound to hold a moving object"
    elif initial is not None and abs(value - initial) < 1e-9:
        out.update(source="default")
    else:
        out.update(source="optimised")
    return out


def com_provenance(com_in_object: np.ndarray, centroid_in_object: np.ndarray,
                   repaired_source: str = "repaired") -> dict:
    """``mesh_centroid`` when the COM is the uniform solid's centroid, else
    ``repaired_source`` with the shift (m) and its vector."""
    d = np.asarray(com_in_object, dtype=float) - np.asarray(centroid_in_object, dtype=float)
    shift = float(np.linalg.norm(d))
    if shift < COM_SHIFT_TOL_M:
        return {"source": "mesh_centroid", "shift_m": shift}
    return {"source": repaired_source, "shift_m": shift,
            "shift_in_object_m": [float(x) for x in d]}


def resolve_physics(item: dict, volume_m3: float, centroid_in_object: np.ndarray,
                    user: Optional[ObjectEntry], density_kg_m3: Optional[float],
                    default_friction: float) -> tuple[float, float, np.ndarray, dict]:
    """Mass (kg), friction, COM (object frame) and provenance of one exported object.

    ``item``: the export stage's record of the object: ``mass_kg``, ``friction``, ``com``
    (None where no stage set them), ``provenance`` (a stage's own record, optional),
    ``fitted`` (names of values a diagnose fit set: "friction", "com") and ``from_gt``.
    A value a stage set is kept; a missing one is filled here (user, table, default).
    """
    prov = dict(item.get("provenance") or {})
    fitted = set(item.get("fitted") or ())
    if item.get("from_gt"):
        prov = {"mass": {"source": "gt"}, "friction": {"source": "gt"}, "com": {"source": "gt"}}
    mass = item.get("mass_kg")
    if user is not None and user.mass_kg is not None:
        mass, prov["mass"] = float(user.mass_kg), {"source": "user", "mass_kg": float(user.mass_kg)}
    elif mass is None:
        mass, prov["mass"] = nominal_mass(item.get("label", ""), volume_m3, user, density_kg_m3)
    elif "mass" not in prov:
        prov["mass"] = {"source": "stage", "stage": item.get("stage")}
    friction = item.get("friction")
    if user is not None and user.friction is not None and "friction" not in fitted:
        friction = float(user.friction)
        prov["friction"] = {"source": "user", "value": friction}
    elif friction is None:
        friction = float(default_friction)
        prov["friction"] = {"source": "default", "value": friction}
    elif "friction" in fitted:
        prov["friction"] = {"source": "fitted_push", "value": float(friction)}
    elif "friction" not in prov:
        prov["friction"] = {"source": "stage", "stage": item.get("stage"),
                            "value": float(friction)}
    com = item.get("com")
    com = np.asarray(centroid_in_object if com is None else com, dtype=float)
    if not item.get("from_gt"):
        prov["com"] = com_provenance(com, centroid_in_object,
                                     "fitted_push" if "com" in fitted else "repaired")
    return float(mass), float(friction), com, prov
