"""Volume, centre of mass and inertia of a (possibly imperfect) shape.

A closed mesh gives exact values; an open one (a foundation-model mesh with holes) falls
back to its convex pieces, whose union approximates the shape.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import trimesh

from r2s.geometry.convex import closed_convex_hull


@dataclass(frozen=True)
class MassProperties:
    """Mass properties in the object frame.

    volume_m3 : float; com_in_object : (3,); inertia_about_com : (3, 3) kg m^2 for mass_kg.
    """

    volume_m3: float
    mass_kg: float
    com_in_object: np.ndarray
    inertia_about_com: np.ndarray


def _solid_parts(mesh: trimesh.Trimesh, pieces: Sequence[trimesh.Trimesh]) -> list[trimesh.Trimesh]:
    if mesh.is_watertight and mesh.volume > 0:
        return [mesh]
    if mesh.is_watertight and mesh.volume < 0:
        fixed = mesh.copy()
        fixed.invert()
        return [fixed]
    parts = [p for p in pieces if p.volume > 0]
    return parts or [closed_convex_hull(mesh)]


def mass_properties(mesh: trimesh.Trimesh, pieces: Sequence[trimesh.Trimesh] = (),
                    mass_kg: float | None = None, density_kg_m3: float = 600.0
                    ) -> MassProperties:
    """Mass properties of ``mesh`` (object frame) for a given mass, else volume x density."""
    parts = _solid_parts(mesh, pieces)
    volume = float(sum(p.volume for p in parts))
    mass = float(mass_kg) if mass_kg is not None else volume * density_kg_m3
    com = sum(p.volume * np.asarray(p.center_mass) for p in parts) / volume
    inertia = np.zeros((3, 3))
    for p in parts:
        m_p = mass * p.volume / volume
        # trimesh's moment_inertia is about the part's own centre of mass for its density
        i_p = np.asarray(p.moment_inertia) * (m_p / max(p.mass, 1e-12))
        d = np.asarray(p.center_mass) - com
        inertia += i_p + m_p * (np.dot(d, d) * np.eye(3) - np.outer(d, d))
    return MassProperties(volume_m3=volume, mass_kg=mass, com_in_object=np.asarray(com),
                          inertia_about_com=inertia)
