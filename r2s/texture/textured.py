"""Between trimesh meshes and the arrays texture refinement works on.

Every mesh leaves here with UVs and a square texture of ``texture_size`` texels:

- a mesh with a texture (a foundation model's, say) keeps its UVs; its image times the
  material's base-colour factor, resampled to the working size, is the initial texture;
- a mesh with vertex (or face) colours, as ``init`` writes them, gets a chart atlas
  (:mod:`r2s.texture.uv`) and its colours baked into the texels;
- a mesh with neither gets the atlas and a uniform grey.

Texels outside every chart (the gutters) copy the nearest chart texel, so bilinear lookups
at chart borders see the chart's colour.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
import torch
import trimesh
from PIL import Image

from r2s.render.shade import DEFAULT_RGB, material_rgb
from r2s.texture.bake import bake_vertex_values, fill_from_nearest, uv_raster
from r2s.texture.uv import chart_atlas


PNG_COMPRESS_LEVEL = 1
"""zlib level of the textures inside written GLBs."""


@dataclass(frozen=True)
class TexturedMesh:
    """A mesh with UVs and a working texture.

    Attributes
    ----------
    vertices : (V, 3) float64, object frame, metres.
    faces : (F, 3) int64.
    uv : (V, 2) float64 UVs (trimesh convention: v up).
    texture : (S, S, 3) float32 RGB in [0, 1], the working texture.
    native : (H0, W0, 3) float32 source texture when it is larger than the working one
        (its detail is kept on export, see :func:`export_texture`), else None.
    origin : "texture", "vertex_colors", "face_colors" or "uniform": where ``texture``
        came from.
    """

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    texture: np.ndarray
    native: Optional[np.ndarray]
    origin: str


def resample(image: np.ndarray, height: int, width: int) -> np.ndarray:
    """(height, width, C) float32 bilinear resample of an (H, W, C) image (antialiased when
    shrinking)."""
    if image.shape[:2] == (height, width):
        return image.astype(np.float32, copy=True)
    t = torch.as_tensor(np.ascontiguousarray(image, dtype=np.float32)).permute(2, 0, 1)[None]
    shrink = height < image.shape[0] or width < image.shape[1]
    out = torch.nn.functional.interpolate(t, size=(height, width), mode="bilinear",
                                          align_corners=False, antialias=shrink)
    return np.ascontiguousarray(out[0].permute(1, 2, 0).numpy(), dtype=np.float32)


def textured_mesh(mesh: trimesh.Trimesh, texture_size: int = 512, gutter_px: int = 2
                  ) -> TexturedMesh:
    """UVs and an initial (texture_size, texture_size) texture for ``mesh`` (module docstring)."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    visual = mesh.visual
    if isinstance(visual, trimesh.visual.TextureVisuals):
        image, factor = material_rgb(visual.material)
        uv = visual.uv
        if image is not None and uv is not None and len(uv) == len(vertices):
            native = (image * factor.astype(np.float32)).astype(np.float32)
            work = resample(native, texture_size, texture_size)
            keep_native = native.shape[0] * native.shape[1] > texture_size ** 2
            return TexturedMesh(vertices, faces, np.asarray(uv, dtype=np.float64), work,
                                native if keep_native else None, "texture")
        per_vertex = np.broadcast_to(factor, (len(vertices), 3))
        origin, per_face = "uniform", None
    elif isinstance(visual, trimesh.visual.ColorVisuals) and visual.kind == "face":
        per_vertex, origin = None, "face_colors"
        per_face = np.asarray(visual.face_colors, dtype=np.float64)[:, :3] / 255.0
    elif isinstance(visual, trimesh.visual.ColorVisuals) and visual.kind == "vertex":
        per_vertex, origin, per_face = (np.asarray(visual.vertex_colors, dtype=np.float64)[:, :3]
                                        / 255.0), "vertex_colors", None
    else:
        per_vertex = np.broadcast_to(DEFAULT_RGB, (len(vertices), 3))
        origin, per_face = "uniform", None

    atlas = chart_atlas(vertices, faces, texture_size, gutter_px)
    face, bary = uv_raster(atlas.uv, atlas.faces, texture_size, texture_size)
    covered = face >= 0
    if per_face is not None:
        texture = np.zeros((texture_size, texture_size, 3), np.float32)
        texture[covered] = per_face[face[covered]]
    else:
        texture = bake_vertex_values(face, bary, atlas.faces,
                                     np.asarray(per_vertex)[atlas.source_vertex])
    texture = fill_from_nearest(np.clip(texture, 0.0, 1.0), covered).astype(np.float32)
    return TexturedMesh(atlas.vertices, atlas.faces, atlas.uv, texture, None, origin)


def export_texture(textured: TexturedMesh, refined: np.ndarray) -> np.ndarray:
    """The texture to save: the refined working texture, or, where the source texture was
    larger, the source plus the upsampled change ``refined - initial`` (so that detail the
    working resolution cannot hold is kept). (H, W, 3) float32 in [0, 1]."""
    if textured.native is None:
        return np.clip(refined, 0.0, 1.0).astype(np.float32)
    h, w = textured.native.shape[:2]
    change = resample(refined - textured.texture, h, w)
    return np.clip(textured.native + change, 0.0, 1.0).astype(np.float32)


def to_trimesh(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, texture: np.ndarray
               ) -> trimesh.Trimesh:
    """A ``trimesh.Trimesh`` with ``TextureVisuals`` (PBR base-colour texture, factor 1).

    ``texture`` is (H, W, 3) float in [0, 1]; it is stored as an 8-bit PNG by GLB export.
    """
    image = Image.fromarray(np.round(np.clip(texture, 0, 1) * 255).astype(np.uint8), "RGB")
    # trimesh re-encodes the image as PNG on GLB export; Pillow reads default save options
    # from ``encoderinfo``: fast zlib level 1 (5x faster than the default 6, ~15 % larger)
    image.encoderinfo = {"compress_level": PNG_COMPRESS_LEVEL}
    material = trimesh.visual.material.PBRMaterial(
        baseColorTexture=image, baseColorFactor=[255, 255, 255, 255], metallicFactor=0.0,
        roughnessFactor=1.0)
    visual = trimesh.visual.TextureVisuals(uv=np.asarray(uv, dtype=np.float64), material=material)
    return trimesh.Trimesh(np.asarray(vertices, dtype=np.float64),
                           np.asarray(faces, dtype=np.int64), visual=visual, process=False)
