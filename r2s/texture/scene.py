"""Texture refinement of a whole scene seen by one camera: G-buffer, samples, renders.

Pure functions on arrays; the ``texture`` stage does the file I/O around them.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy import ndimage

from r2s.geometry.camera import transform_points
from r2s.render.gbuffer import GBuffer, interpolate, rasterize
from r2s.render.shade import MeshColour, shade
from r2s.render.texel import bilinear_footprint
from r2s.texture.refine import PixelSamples
from r2s.texture.textured import TexturedMesh


class _Posed:
    """Vertices placed in the world frame, faces as given (what :func:`rasterize` needs)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        self.vertices = vertices
        self.faces = faces


def scene_gbuffer(meshes: Sequence[TexturedMesh], world_from_object: Sequence[np.ndarray],
                  K: np.ndarray, world_from_camera: np.ndarray, width: int, height: int
                  ) -> GBuffer:
    """G-buffer of the objects (object-frame meshes, (4, 4) poses) seen by the camera."""
    posed = [_Posed(transform_points(pose, m.vertices), m.faces)
             for m, pose in zip(meshes, world_from_object)]
    return rasterize(posed, K, world_from_camera, width, height)


def observed_pixels(gbuffer: GBuffer, masks: np.ndarray, ids: Sequence[int],
                    erode_px: int = 1) -> list[np.ndarray]:
    """Per object, (H, W) bool pixels whose render and instance mask both say "this object".

    ``ids[i]`` is the instance id of mesh ``i``. Each agreement region is eroded by
    ``erode_px`` pixels so that pixels mixing the object with its surroundings at the
    silhouette are left out.
    """
    out = []
    structure = ndimage.generate_binary_structure(2, 1)
    for index, obj_id in enumerate(ids):
        agree = (gbuffer.object_index == index) & (masks == obj_id)
        if erode_px > 0 and agree.any():
            agree = ndimage.binary_erosion(agree, structure, iterations=erode_px)
        out.append(agree)
    return out


def pixel_samples(gbuffer: GBuffer, index: int, mesh: TexturedMesh, region: np.ndarray,
                  rgb: np.ndarray) -> PixelSamples:
    """The texel footprints and observed colours of one object's pixels in ``region`` (H, W) bool.

    ``rgb`` is the observed (H, W, 3) uint8 image.
    """
    pixels, uv = interpolate(gbuffer, index, mesh.faces, mesh.uv)
    keep = region[pixels[:, 0], pixels[:, 1]]
    pixels, uv = pixels[keep], uv[keep]
    size = mesh.texture.shape[:2]
    idx, wts = bilinear_footprint(uv, size[0], size[1])
    observed = rgb[pixels[:, 0], pixels[:, 1]].astype(np.float32) / 255.0
    return PixelSamples(index=idx, weight=wts, observed=observed)


def render_textures(gbuffer: GBuffer, meshes: Sequence[TexturedMesh],
                    textures: Sequence[np.ndarray]) -> np.ndarray:
    """(H, W, 3) uint8 render of the G-buffer with the given textures (black background)."""
    colours = [MeshColour(uv=m.uv, texture=t) for m, t in zip(meshes, textures)]
    rgb = shade(gbuffer, [m.faces for m in meshes], colours)
    return np.round(rgb * 255.0).astype(np.uint8)
