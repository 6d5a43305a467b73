"""The textured visual mesh as files simulators read: OBJ + MTL + PNG (MuJoCo, PyBullet).

``visual/<id>.obj`` holds positions, texture coordinates (OBJ convention: v up, origin at
the image's bottom-left, as trimesh stores them) and triangles in the object frame;
``visual/<id>.png`` is the base-colour texture and ``visual/<id>.mtl`` binds it
(``map_Kd``). A mesh without a texture is written with its mean colour in the MTL.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import trimesh
from PIL import Image

from r2s.io.atomic import atomic_write_bytes, atomic_write_text
from r2s.io.mesh_io import PNG_COMPRESS_LEVEL


def texture_image(mesh: trimesh.Trimesh) -> Optional[Image.Image]:
    """The base-colour texture of a textured mesh (RGB or RGBA), else None."""
    visual = mesh.visual
    if not isinstance(visual, trimesh.visual.TextureVisuals) or visual.uv is None:
        return None
    mat = visual.material
    image = getattr(mat, "baseColorTexture", None) or getattr(mat, "image", None)
    return image if isinstance(image, Image.Image) else None


def mean_rgba(mesh: trimesh.Trimesh) -> np.ndarray:
    """(4,) mean colour in [0, 1] (the texture's mean for a textured mesh)."""
    image = texture_image(mesh)
    if image is not None:
        rgb = np.asarray(image.convert("RGB"), dtype=float).reshape(-1, 3).mean(0) / 255.0
        return np.append(rgb, 1.0)
    try:
        colours = np.asarray(mesh.visual.to_color().vertex_colors, dtype=float)
        return colours.reshape(-1, 4).mean(0) / 255.0
    except Exception:
        return np.array([0.7, 0.7, 0.7, 1.0])


@dataclass(frozen=True)
class VisualFiles:
    """Paths (relative to the export folder) of one visual mesh's files."""

    obj: str
    png: Optional[str]
    rgba: tuple[float, float, float, float]


def write_visual_obj(mesh: trimesh.Trimesh, out_dir: Path, stem: str) -> VisualFiles:
    """Write ``out_dir/visual/<stem>.obj|.mtl|.png``; returns their paths relative to
    ``out_dir``."""
    image = texture_image(mesh)
    rgba = tuple(float(x) for x in mean_rgba(mesh))
    v = np.asarray(mesh.vertices, dtype=float)
    f = np.asarray(mesh.faces, dtype=np.int64) + 1
    lines = [f"mtllib {stem}.mtl", f"usemtl {stem}"]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in v]
    if image is not None:
        uv = np.asarray(mesh.visual.uv, dtype=float)
        lines += [f"vt {a:.9g} {b:.9g}" for a, b in uv]
        lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in f]
    else:
        lines += [f"f {a} {b} {c}" for a, b, c in f]
    kd = (1.0, 1.0, 1.0) if image is not None else rgba[:3]
    mtl = [f"newmtl {stem}", "Ka 0 0 0", "Kd {:.6g} {:.6g} {:.6g}".format(*kd),
           "Ks 0 0 0", "d 1"]
    png = None
    if image is not None:
        png = f"visual/{stem}.png"
        buf = io.BytesIO()
        image.convert("RGB").save(buf, format="PNG", compress_level=PNG_COMPRESS_LEVEL)
        atomic_write_bytes(Path(out_dir) / png, buf.getvalue())
        mtl.append(f"map_Kd {stem}.png")
    atomic_write_text(Path(out_dir) / f"visual/{stem}.mtl", "\n".join(mtl) + "\n")
    atomic_write_text(Path(out_dir) / f"visual/{stem}.obj", "\n".join(lines) + "\n")
    return VisualFiles(obj=f"visual/{stem}.obj", png=png, rgba=rgba)
