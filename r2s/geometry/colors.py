"""Vertex colours of a posed mesh from the observed RGB image.

A vertex takes the colour of the pixel it projects to when the camera actually sees it
there (the observed depth agrees with the vertex depth, and the pixel belongs to the
instance); every other vertex takes the colour of the nearest seen vertex.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from r2s.geometry.camera import image_pixels


def has_appearance(mesh: trimesh.Trimesh) -> bool:
    """True when the mesh carries a texture image or per-vertex / per-face colours."""
    visual = mesh.visual
    if isinstance(visual, trimesh.visual.TextureVisuals):
        material = visual.material
        image = getattr(material, "baseColorTexture", None) or getattr(material, "image", None)
        return image is not None and visual.uv is not None
    return bool(getattr(visual, "defined", False)) and visual.kind in ("vertex", "face")


def visible_vertex_colors(vertices_world: np.ndarray, rgb: np.ndarray, depth_m: np.ndarray,
                          K: np.ndarray, world_from_camera: np.ndarray,
                          own_mask: np.ndarray | None = None,
                          depth_tolerance_m: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Colour of each vertex the camera sees.

    Parameters
    ----------
    vertices_world : (V, 3) world frame.
    rgb : (H, W, 3) uint8; depth_m : (H, W) metres, NaN = no reading.
    K : (3, 3); world_from_camera : (4, 4).
    own_mask : (H, W) bool, the instance's pixels, or None (any pixel).
    depth_tolerance_m : how far the observed depth may be from the vertex depth.

    Returns
    -------
    colors : (V, 3) uint8 (zeros where not seen).
    seen : (V,) bool.
    """
    ok, r, c, _, z = image_pixels(vertices_world, K, world_from_camera, *depth_m.shape)
    d = depth_m[r, c]
    seen = ok & np.isfinite(d) & (np.abs(d - z) < depth_tolerance_m)
    if own_mask is not None:
        seen &= np.asarray(own_mask, dtype=bool)[r, c]
    colors = np.zeros((len(z), 3), dtype=np.uint8)
    colors[seen] = rgb[r[seen], c[seen], :3]
    return colors, seen


def color_mesh_from_image(mesh_object: trimesh.Trimesh, world_from_object: np.ndarray,
                          rgb: np.ndarray, depth_m: np.ndarray, K: np.ndarray,
                          world_from_camera: np.ndarray, own_mask: np.ndarray | None = None,
                          depth_tolerance_m: float = 0.01) -> trimesh.Trimesh:
    """A copy of ``mesh_object`` with vertex colours from the image.

    Unseen vertices copy the nearest seen vertex; with no seen vertex at all, every vertex
    gets the mean colour of ``own_mask`` (grey without a mask).
    """
    out = trimesh.Trimesh(np.asarray(mesh_object.vertices), np.asarray(mesh_object.faces),
                          process=False)
    t = np.asarray(world_from_object, dtype=np.float64)
    verts_w = out.vertices @ t[:3, :3].T + t[:3, 3]
    colors, seen = visible_vertex_colors(verts_w, rgb, depth_m, K, world_from_camera,
                                         own_mask, depth_tolerance_m)
    if seen.any():
        if not seen.all():
            _, nn = cKDTree(out.vertices[seen]).query(out.vertices[~seen])
            colors[~seen] = colors[seen][nn]
    else:
        if own_mask is not None and np.any(own_mask):
            mean = rgb[np.asarray(own_mask, dtype=bool)][:, :3].mean(axis=0)
        else:
            mean = np.array([128.0, 128.0, 128.0])
        colors[:] = np.rint(mean).astype(np.uint8)
    rgba = np.concatenate([colors, np.full((len(colors), 1), 255, np.uint8)], axis=1)
    out.visual = trimesh.visual.ColorVisuals(out, vertex_colors=rgba)
    return out
