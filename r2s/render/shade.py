"""Colour a G-buffer from each mesh's texture or vertex colours (albedo only, no lighting).

r2s's texture is the observed radiance (the paper's choice with a single view), so a
render is a plain lookup: no lights, no shading.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
import trimesh

from r2s.render.gbuffer import GBuffer, interpolate
from r2s.render.texel import bilinear_footprint, sample

DEFAULT_RGB = (0.5, 0.5, 0.5)
"""Colour of a mesh that carries neither texture nor colours."""


@dataclass(frozen=True)
class MeshColour:
    """How one mesh is coloured: either a texture with UVs or per-vertex colours.

    Attributes
    ----------
    uv : (V, 2) float UVs (trimesh convention) or None.
    texture : (H, W, 3) float32 RGB in [0, 1] or None.
    vertex_rgb : (V, 3) float RGB in [0, 1] (used when there is no texture) or None.
    """

    uv: Optional[np.ndarray] = None
    texture: Optional[np.ndarray] = None
    vertex_rgb: Optional[np.ndarray] = None

    @property
    def textured(self) -> bool:
        return self.uv is not None and self.texture is not None


def material_rgb(material: object) -> tuple[Optional[np.ndarray], np.ndarray]:
    """A trimesh material's base-colour image and factor.

    Returns (H, W, 3) float32 in [0, 1] or None, and the (3,) RGB factor in [0, 1].
    """
    image = getattr(material, "baseColorTexture", None)
    if image is None:
        image = getattr(material, "image", None)
    factor = getattr(material, "baseColorFactor", None)
    if factor is None:
        factor = getattr(material, "diffuse", None)
    rgb_factor = np.ones(3)
    if factor is not None:
        f = np.asarray(factor, dtype=np.float64).reshape(-1)[:3]
        rgb_factor = f / 255.0 if f.max() > 1.0 else f
    if image is None:
        return None, rgb_factor
    arr = np.asarray(image.convert("RGB"), dtype=np.float32) / 255.0
    return arr, rgb_factor


def mesh_colour(mesh: trimesh.Trimesh) -> MeshColour:
    """The colour source of a trimesh: its texture when it has UVs and an image, else vertex
    colours."""
    visual = mesh.visual
    if isinstance(visual, trimesh.visual.TextureVisuals):
        image, factor = material_rgb(visual.material)
        uv = None if visual.uv is None else np.asarray(visual.uv, dtype=np.float64)
        if image is not None and uv is not None and len(uv) == len(mesh.vertices):
            return MeshColour(uv=uv, texture=(image * factor).astype(np.float32))
        rgb = np.broadcast_to(factor, (len(mesh.vertices), 3)).copy()
        return MeshColour(vertex_rgb=rgb)
    if isinstance(visual, trimesh.visual.ColorVisuals) and visual.kind is not None:
        rgb = np.asarray(visual.vertex_colors, dtype=np.float64)[:, :3] / 255.0
        return MeshColour(vertex_rgb=rgb)
    return MeshColour(vertex_rgb=np.broadcast_to(DEFAULT_RGB, (len(mesh.vertices), 3)).copy())


def shade(gbuffer: GBuffer, faces: Sequence[np.ndarray], colours: Sequence[MeshColour],
          background_rgb: Sequence[float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """RGB image of a G-buffer.

    Parameters
    ----------
    gbuffer : from :func:`r2s.render.gbuffer.rasterize` of the same meshes, same order.
    faces : per mesh, (F, 3) int faces (index the mesh's vertices / UVs / vertex colours).
    colours : per mesh, its :class:`MeshColour`.
    background_rgb : colour of pixels that see no mesh, in [0, 1].

    Returns
    -------
    (H, W, 3) float32 RGB in [0, 1].
    """
    h, w = gbuffer.shape
    out = np.empty((h, w, 3), np.float32)
    out[:] = np.asarray(background_rgb, dtype=np.float32)
    for index, (f, colour) in enumerate(zip(faces, colours)):
        if not (gbuffer.object_index == index).any():
            continue
        if colour.textured:
            pixels, uv = interpolate(gbuffer, index, f, colour.uv)
            th, tw = colour.texture.shape[:2]
            idx, wts = bilinear_footprint(uv, th, tw)
            rgb = sample(colour.texture, idx, wts)
        else:
            pixels, rgb = interpolate(gbuffer, index, f, colour.vertex_rgb)
        out[pixels[:, 0], pixels[:, 1]] = np.clip(rgb, 0.0, 1.0)
    return out
