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


PNG_COMPRESS_LEVEL = 3
"""zlib level of the PNG textures inside written GLBs (Pillow's default is 6). A 1024 x
1024 SAM 3D texture: 0.40 s and 973 kB at 6, 0.11 s and 1093 kB at 3 (lossless either
way); the seed demo's export encodes each texture three times."""
_TEXTURE_SLOTS = ("baseColorTexture", "image", "metallicRoughnessTexture", "normalTexture",
                  "emissiveTexture", "occlusionTexture")


def fast_png_textures(meshes) -> None:
    """Ask Pillow to encode the texture images of ``meshes`` (Trimesh objects) at
    ``PNG_COMPRESS_LEVEL`` whenever they are saved without an explicit level (trimesh's
    GLB writer saves them so). Sets the images' ``encoderinfo``, which Pillow 13 (the
    version installed here) merges into every save; a Pillow that does not simply
    encodes at its default level. PNG is lossless: the texels are the same either way."""
    for mesh in meshes:
        material = getattr(getattr(mesh, "visual", None), "material", None)
        for slot in _TEXTURE_SLOTS:
            image = getattr(material, slot, None)
            if image is not None and hasattr(image, "save"):
                info = dict(getattr(image, "encoderinfo", None) or {})
                info.setdefault("compress_level", PNG_COMPRESS_LEVEL)
                image.encoderinfo = info


def mesh_bytes(mesh: trimesh.Trimesh, file_type: str) -> bytes:
    fast_png_textures([mesh])
    data = mesh.export(file_type=file_type)
    if isinstance(data, str):
        data = data.encode()
    return data


def save_mesh(mesh: trimesh.Trimesh, path: Path) -> None:
    """Save atomically; the format follows the suffix (.glb, .obj, .ply, .stl)."""
    path = Path(path)
    atomic_write_bytes(path, mesh_bytes(mesh, path.suffix.lstrip(".").lower()))


def welded(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Geometry only: vertices split along UV seams or normals merged back (a textured GLB
    is stored with seams split, which breaks watertightness, volume and decomposition)."""
    geom = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), process=False)
    geom.merge_vertices(merge_tex=True, merge_norm=True)
    return geom


def untextured(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The same triangles with vertex colours only (for OBJ files without materials)."""
    out = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), process=False)
    try:
        out.visual = trimesh.visual.ColorVisuals(out, vertex_colors=mesh.visual.to_color().vertex_colors)
    except Exception:
        pass
    return out


def _triangle_rows(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """The mesh's triangles independent of vertex and face order: the sorted distinct
    vertices (U, 3) and, per face, their ranks in that list (F, 3), each face rotated to
    start at its lowest rank (winding kept), rows sorted."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    unique, inverse = np.unique(vertices, axis=0, return_inverse=True)
    ranks = inverse.reshape(-1)[np.asarray(mesh.faces, dtype=np.int64)]
    start = np.argmin(ranks, axis=1)
    rows = ranks[np.arange(len(ranks))[:, None], (start[:, None] + np.arange(3)) % 3]
    return unique, rows[np.lexsort(rows.T[::-1])]


def same_triangles(a: trimesh.Trimesh, b: trimesh.Trimesh) -> bool:
    """Whether two meshes hold exactly the same triangles (same vertex coordinates, same
    winding), whatever the order of their vertices and faces. A triangle with a repeated
    vertex may compare unequal to itself rotated (a false "different", never a false
    "same")."""
    if len(a.faces) != len(b.faces):
        return False
    ua, ra = _triangle_rows(a)
    ub, rb = _triangle_rows(b)
    return ua.shape == ub.shape and bool(np.array_equal(ua, ub)) and bool(np.array_equal(ra, rb))
