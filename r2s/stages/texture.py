"""The ``texture`` stage: photometric texture refinement with geometry and poses fixed.

Reads the latest geometry state (physopt > geomopt > init, or ``source``) and ``input/``
(rgb, masks, camera). Every object mesh gets UVs and a texture (its own texture when it has
one, else a chart atlas with its vertex colours baked in); the scene is ray-cast once from
the input camera (nearest hit: occlusion between objects), and the textures are optimised
so that the render matches ``rgb.png`` on each object's pixels where render and mask agree
(L1), with an isotropic TV prior (:mod:`r2s.texture.refine`). For a mesh that came with
its own texture (a foundation model's) the TV term acts on the change from that texture
(``tv_on=auto``), so that what the camera did not see keeps the model's guess; a texture
larger than ``texture_size`` is written at its own resolution (source + upsampled change).

Writes ``texture/``::

    state.json          the source state, stage "texture", meshes -> meshes/<id>.glb
    meshes/<id>.glb     textured meshes (object frame, UVs + PNG base-colour texture)
    before_after.png    observed | before | after | |after - observed|
    metrics.json        PSNR / SSIM over the object pixels before and after, per object too
"""

from __future__ import annotations

import io
import time
from pathlib import Path
from typing import Literal

import numpy as np
from PIL import Image
from pydantic import Field

from r2s.scene_model import corrected_input
from r2s.errors import StageError
from r2s.io.atomic import atomic_write_bytes, atomic_write_json
from r2s.io.input_scene import load_input
from r2s.io.mesh_io import load_mesh, save_mesh
from r2s.io.paths import METRICS_FILE, ScenePaths
from r2s.io.state import read_state, write_state
from r2s.metrics.rendering import masked_psnr, rendering_metrics, side_by_side, ssim_map
from r2s.render.shade import mesh_colour, shade
from r2s.runner.base import StageContext, StageOptions, StageSpec
from r2s.io.manifest import Manifest
from r2s.io.latest_state import GEOMETRY_STAGES, latest_state_stage
from r2s.texture.refine import RefineOptions, refine_textures, seen_texels
from r2s.texture.scene import observed_pixels, pixel_samples, render_textures, scene_gbuffer
from r2s.texture.textured import export_texture, textured_mesh, to_trimesh


class Options(StageOptions):
    source: Literal["auto", "init", "geomopt", "physopt"] = Field(
        "auto", description="Which geometry to texture: the latest stage that ran, or a named one.")
    texture_size: int = Field(256, ge=16, le=4096,
                              description="Side of the square working texture, texels.")
    iterations: int = Field(200, ge=0, description="Adam iterations.")
    lr: float = Field(0.02, gt=0, description="Adam learning rate (texel values in [0, 1]).")
    lambda_tv: float = Field(0.5, ge=0, description="Weight of the isotropic TV term.")
    tv_on: Literal["auto", "texture", "change"] = Field(
        "auto", description="What the TV term smooths: the texture (the paper), the change "
                            "from the initial texture (keeps a mesh's own texture where unseen), "
                            "or auto: the change for meshes that came with a texture.")
    mask_erode_px: int = Field(1, ge=0, description="Pixels dropped at each object's silhouette.")
    seed: int = Field(0, description="Torch seed.")


def _source(paths: ScenePaths, options: Options, manifest: Manifest) -> str:
    return latest_state_stage(paths, manifest, None if options.source == "auto" else options.source,
                              candidates=GEOMETRY_STAGES)


def inputs(paths: ScenePaths, options: Options, manifest: Manifest) -> list[Path]:
    try:
        source = _source(paths, options, manifest)
    except StageError:
        return [paths.input]
    return [paths.stage_dir(source), paths.input]


def _png_bytes(image: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG", compress_level=1)
    return buf.getvalue()


def run(ctx: StageContext) -> dict:
    paths, opt = ctx.paths, ctx.options
    t_start = time.perf_counter()
    source = _source(paths, opt, ctx.manifest)
    src_dir = paths.stage_dir(source)
    state = read_state(src_dir)
    # the camera as the scene's model corrects it (the states live in init's world frame)
    scene = corrected_input(load_input(paths.root), ctx.manifest.model)
    cam = scene.camera

    sources, meshes = [], []
    for k, obj in enumerate(state.objects):
        ctx.progress(f"object {obj.id}: UV texture", 0.1 * k / max(len(state.objects), 1))
        sources.append(load_mesh(src_dir / obj.mesh))
        meshes.append(textured_mesh(sources[-1], opt.texture_size))
    t_prepared = time.perf_counter()

    poses = [obj.pose for obj in state.objects]
    gbuffer = scene_gbuffer(meshes, poses, cam.K, cam.world_from_camera, cam.width, cam.height)
    ids = [obj.id for obj in state.objects]
    regions = observed_pixels(gbuffer, scene.masks, ids, opt.mask_erode_px)
    samples = [pixel_samples(gbuffer, k, m, regions[k], scene.rgb) for k, m in enumerate(meshes)]
    t_raster = time.perf_counter()

    initial = [m.texture for m in meshes]
    result = refine_textures(
        initial, samples,
        RefineOptions(iterations=opt.iterations, lr=opt.lr, lambda_tv=opt.lambda_tv, seed=opt.seed),
        progress=lambda msg, f: ctx.progress(msg, 0.1 + 0.8 * f),
        tv_reference=[opt.tv_on == "change" or (opt.tv_on == "auto" and m.origin == "texture")
                      for m in meshes])
    t_refined = time.perf_counter()

    # before: the source meshes with their own colours (textured meshes keep their faces'
    # order, so the G-buffer's face ids index both); after: exactly the textures written
    before = np.round(shade(gbuffer, [np.asarray(m.faces) for m in sources],
                            [mesh_colour(m) for m in sources]) * 255).astype(np.uint8)
    final = [export_texture(m, t) for m, t in zip(meshes, result.textures)]
    after = render_textures(gbuffer, meshes, final)
    object_mask = scene.masks > 0
    metrics_before = rendering_metrics(scene.rgb, before, object_mask)
    metrics_after = rendering_metrics(scene.rgb, after, object_mask)
    ssim_before = ssim_map(scene.rgb, before, object_mask)
    ssim_after = ssim_map(scene.rgb, after, object_mask)

    ctx.progress("writing textured meshes", 0.9)
    out_state = state.model_copy(deep=True)
    out_state.stage = "texture"
    per_object = []
    for k, (obj, mesh) in enumerate(zip(out_state.objects, meshes)):
        rel = f"meshes/{obj.id}.glb"
        texture = final[k]
        save_mesh(to_trimesh(mesh.vertices, mesh.faces, mesh.uv, texture), ctx.out_dir / rel)
        obj.mesh = rel
        setattr(obj, "texture_origin", mesh.origin)
        own = scene.masks == obj.id
        per_object.append({
            "id": obj.id,
            "texture_origin": mesh.origin,
            "texture_shape": list(texture.shape[:2]),
            "observed_pixels": samples[k].count,
            "seen_texel_fraction": float(seen_texels(samples[k], mesh.texture.shape[:2]).mean()),
            "psnr_before": masked_psnr(scene.rgb, before, own),
            "psnr_after": masked_psnr(scene.rgb, after, own),
            "ssim_before": float(ssim_before[own].mean()) if own.any() else None,
            "ssim_after": float(ssim_after[own].mean()) if own.any() else None,
        })
    write_state(ctx.out_dir, out_state)

    atomic_write_bytes(ctx.out_dir / "before_after.png", _png_bytes(side_by_side(
        [scene.rgb, before, after], ["observed", "before", "after"], object_mask)))
    summary = {
        "source": source,
        "psnr_before": metrics_before["psnr"], "psnr_after": metrics_after["psnr"],
        "ssim_before": metrics_before["ssim"], "ssim_after": metrics_after["ssim"],
    }
    t_end = time.perf_counter()
    atomic_write_json(ctx.out_dir / METRICS_FILE, {
        **summary,
        "before": metrics_before,
        "after": metrics_after,
        "objects": per_object,
        "loss_first": result.loss[0] if result.loss else None,
        "loss_last": result.loss[-1] if result.loss else None,
        "photo_l1_first": result.photo_l1[0] if result.photo_l1 else None,
        "photo_l1_last": result.photo_l1[-1] if result.photo_l1 else None,
        "seconds": {
            "uv_textures": round(t_prepared - t_start, 3),
            "rasterise": round(t_raster - t_prepared, 3),
            "refine": round(t_refined - t_raster, 3),
            "write": round(t_end - t_refined, 3),
        },
    })
    ctx.progress("done", 1.0)
    return summary


STAGE = StageSpec("texture", Options, inputs, run, uses_model=frozenset({"input"}))
