"""Texture refinement of a whole scene from one camera: UVs, one ray-cast G-buffer, the
photometric refinement, and the renders and metrics before and after.

Inputs are loaded data (meshes in their object frames, (4, 4) ``world_from_object`` poses, an
input view); nothing here reads or writes files. ``r2s.stages.texture`` writes the result.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numpy as np
import trimesh

from r2s.metrics.rendering import masked_psnr, rendering_metrics, ssim_map
from r2s.render.shade import mesh_colour, shade
from r2s.texture.refine import RefineOptions, RefineResult, refine_textures, seen_texels
from r2s.texture.scene import observed_pixels, pixel_samples, render_textures, scene_gbuffer
from r2s.texture.textured import TexturedMesh, export_texture, textured_mesh


@dataclass(frozen=True)
class SceneTextures:
    """What the refinement produced.

    meshes : the textured meshes (object frame, UVs), one per object, in input order.
    textures : (h, w, 3) uint8 textures to write with them.
    before, after : (H, W, 3) uint8 renders from the input camera with the source meshes'
        own colours and with the refined textures.
    per_object : per-object metrics (observed pixels, seen texels, PSNR / SSIM before/after).
    metrics_before, metrics_after : PSNR / SSIM over all object pixels.
    result : the optimiser's record (loss curves).
    """

    meshes: list[TexturedMesh]
    textures: list[np.ndarray]
    before: np.ndarray
    after: np.ndarray
    per_object: list[dict]
    metrics_before: dict
    metrics_after: dict
    result: RefineResult


def refine_scene_textures(sources: Sequence[trimesh.Trimesh], poses: Sequence[np.ndarray],
                          ids: Sequence[int], camera, rgb: np.ndarray, masks: np.ndarray,
                          options: RefineOptions, texture_size: int, mask_erode_px: int,
                          tv_on: str,
                          progress: Optional[Callable[[str, float], None]] = None
                          ) -> SceneTextures:
    """Refine every object's texture so that the render from ``camera`` matches ``rgb``.

    ``camera``: an input camera (``K`` (3, 3), ``world_from_camera`` (4, 4), ``width``,
    ``height``); ``rgb`` (H, W, 3) uint8; ``masks`` (H, W) instance ids. ``tv_on``: "auto",
    "texture" or "change" (see the stage's option). Progress fractions run 0 to 0.9.
    """
    report = progress or (lambda _msg, _f: None)
    meshes = []
    for k, (oid, src) in enumerate(zip(ids, sources)):
        report(f"object {oid}: UV texture", 0.1 * k / max(len(sources), 1))
        meshes.append(textured_mesh(src, texture_size))
    gbuffer = scene_gbuffer(meshes, list(poses), camera.K, camera.world_from_camera,
                            camera.width, camera.height)
    regions = observed_pixels(gbuffer, masks, list(ids), mask_erode_px)
    samples = [pixel_samples(gbuffer, k, m, regions[k], rgb) for k, m in enumerate(meshes)]
    result = refine_textures(
        [m.texture for m in meshes], samples, options,
        progress=lambda msg, f: report(msg, 0.1 + 0.8 * f),
        tv_reference=[tv_on == "change" or (tv_on == "auto" and m.origin == "texture")
                      for m in meshes])
    # before: the source meshes with their own colours (textured meshes keep their faces'
    # order, so the G-buffer's face ids index both); after: exactly the textures written
    before = np.round(shade(gbuffer, [np.asarray(m.faces) for m in sources],
                            [mesh_colour(m) for m in sources]) * 255).astype(np.uint8)
    final = [export_texture(m, t) for m, t in zip(meshes, result.textures)]
    after = render_textures(gbuffer, meshes, final)
    object_mask = masks > 0
    ssim_before = ssim_map(rgb, before, object_mask)
    ssim_after = ssim_map(rgb, after, object_mask)
    per_object = []
    for k, (oid, mesh) in enumerate(zip(ids, meshes)):
        own = masks == oid
        per_object.append({
            "id": oid,
            "texture_origin": mesh.origin,
            "texture_shape": list(final[k].shape[:2]),
            "observed_pixels": samples[k].count,
            "seen_texel_fraction": float(seen_texels(samples[k], mesh.texture.shape[:2]).mean()),
            "psnr_before": masked_psnr(rgb, before, own),
            "psnr_after": masked_psnr(rgb, after, own),
            "ssim_before": float(ssim_before[own].mean()) if own.any() else None,
            "ssim_after": float(ssim_after[own].mean()) if own.any() else None,
        })
    return SceneTextures(meshes, final, before, after, per_object,
                         rendering_metrics(rgb, before, object_mask),
                         rendering_metrics(rgb, after, object_mask), result)
