"""The generator's file writers: scene images, textured .obj visuals, collision .obj pieces.

Scene files go through :mod:`r2s.io.atomic`; visuals and pieces are scratch files for
PyBullet in a temporary folder.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from r2s.io.atomic import atomic_write_bytes


def png_bytes(image: np.ndarray) -> bytes:
    """PNG of an (H, W, 3) uint8, (H, W) uint8 or (H, W) uint16 array."""
    arr = np.ascontiguousarray(image)
    if arr.dtype == np.uint16:
        if arr.ndim != 2:
            raise ValueError("16-bit images must be single-channel")
        img = Image.fromarray(arr)
    else:
        img = Image.fromarray(arr.astype(np.uint8))
    buf = io.BytesIO()
    img.save(buf, format="PNG")
    return buf.getvalue()


def write_png(path: Path, image: np.ndarray) -> None:
    atomic_write_bytes(Path(path), png_bytes(image))


def depth_png(depth_m: np.ndarray, depth_unit_m: float) -> np.ndarray:
    """(H, W) uint16 depth in ``depth_unit_m`` units; 0 where NaN, non-positive or too far."""
    z = np.asarray(depth_m, dtype=np.float64)
    units = np.where(np.isfinite(z) & (z > 0), np.round(z / depth_unit_m), 0.0)
    units[units > np.iinfo(np.uint16).max] = 0
    return units.astype(np.uint16)


def write_textured_obj(path: Path, mesh: trimesh.Trimesh) -> None:
    """Write ``mesh`` (with ``visual.uv``) as an .obj with positions, uvs and normals."""
    verts = np.asarray(mesh.vertices)
    uv = np.asarray(mesh.visual.uv)
    normals = np.asarray(mesh.vertex_normals)
    faces = np.asarray(mesh.faces) + 1
    lines = ["# r2s synth visual"]
    lines += [f"v {x:.7f} {y:.7f} {z:.7f}" for x, y, z in verts]
    lines += [f"vt {u:.6f} {v:.6f}" for u, v in uv]
    lines += [f"vn {x:.5f} {y:.5f} {z:.5f}" for x, y, z in normals]
    lines += [f"f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}" for a, b, c in faces]
    Path(path).write_text("\n".join(lines) + "\n")


def write_piece_objs(folder: Path, stem: str, pieces: list[trimesh.Trimesh]) -> list[Path]:
    """Write convex pieces as ``folder/<stem>_<k>.obj``; returns the paths."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for k, piece in enumerate(pieces):
        path = folder / f"{stem}_{k}.obj"
        piece.export(path, file_type="obj")
        paths.append(path)
    return paths
