"""Mesh files: load any of GLB / OBJ / PLY / STL as one ``trimesh.Trimesh``, save GLB or OBJ."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import trimesh

from r2s.errors import InputError
from r2s.io.atomic import atomic_write_bytes


def load_mesh(path: Path) -> trimesh.Trimesh:
    """Load a mesh file (scenes are flattened with their node transforms) as one Trimesh.

    Raises :class:`InputError` for a missing, unreadable or empty mesh.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "missing mesh file")
    try:
        loaded = trimesh.load(path, process=False, force=None)
    except Exception as exc:  # trimesh raises many types
        raise InputError(path, f"unreadable mesh ({type(exc).__name__})") from None
    if isinstance(loaded, trimesh.Scene):
        geoms = [g for g in loaded.dump(concatenate=False) if isinstance(g, trimesh.Trimesh)]
        if not geoms:
            raise InputError(path, "mesh file holds no triangles")
        mesh = geoms[0] if len(geoms) == 1 else trimesh.util.concatenate(geoms)
    elif isinstance(loaded, trimesh.Trimesh):
        mesh = loaded
    else:
        raise InputError(path, f"mesh file holds no triangles ({type(loaded).__name__})")
    if len(mesh.faces) == 0 or not np.all(np.isfinite(mesh.vertices)):
        raise InputError(path, "mesh has no faces or non-finite vertices")
    return mesh


def mesh_bytes(mesh: trimesh.Trimesh, file_type: str) -> bytes:
    data = mesh.export(file_type=file_type)
    if isinstance(data, str):
        data = data.encode()
    return data


def save_mesh(mesh: trimesh.Trimesh, path: Path) -> None:
    """Save atomically; the format follows the suffix (.glb, .obj, .ply, .stl)."""
    path = Path(path)
    atomic_write_bytes(path, mesh_bytes(mesh, path.suffix.lstrip(".").lower()))
