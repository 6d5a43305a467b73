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
from r2s.metrics.rendering import side_by_side
from r2s.runner.base import StageContext, StageOptions, StageSpec
from r2s.io.manifest import Manifest
from r2s.io.latest_state import GEOMETRY_STAGES, latest_state_stage
from r2s.texture.refine import RefineOptions
from r2s.texture.scene_refine import refine_scene_textures
from r2s.texture.textured import to_trimesh


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
    done = refine_scene_textures(
        [load_mesh(src_dir / obj.mesh) for obj in state.objects],
        [obj.pose for obj in state.objects], [obj.id for obj in state.objects],
        scene.camera, scene.rgb, scene.masks,
        RefineOptions(iterations=opt.iterations, lr=opt.lr, lambda_tv=opt.lambda_tv,
                      seed=opt.seed),
        opt.texture_size, opt.mask_erode_px, opt.tv_on, ctx.progress)
    t_refined = time.perf_counter()

    ctx.progress("writing textured meshes", 0.9)
    out_state = state.model_copy(deep=True)
    out_state.stage = "texture"
    for obj, mesh, texture in zip(out_state.objects, done.meshes, done.textures):
        obj.mesh = f"meshes/{obj.id}.glb"
        save_mesh(to_trimesh(mesh.vertices, mesh.faces, mesh.uv, texture), ctx.out_dir / obj.mesh)
        setattr(obj, "texture_origin", mesh.origin)
    write_state(ctx.out_dir, out_state)
    atomic_write_bytes(ctx.out_dir / "before_after.png", _png_bytes(side_by_side(
        [scene.rgb, done.before, done.after], ["observed", "before", "after"],
        scene.masks > 0)))
    summary = {
        "source": source,
        "psnr_before": done.metrics_before["psnr"], "psnr_after": done.metrics_after["psnr"],
        "ssim_before": done.metrics_before["ssim"], "ssim_after": done.metrics_after["ssim"],
    }
    loss, photo = done.result.loss, done.result.photo_l1
    atomic_write_json(ctx.out_dir / METRICS_FILE, {
        **summary, "before": done.metrics_before, "after": done.metrics_after,
        "objects": done.per_object,
        "loss_first": loss[0] if loss else None, "loss_last": loss[-1] if loss else None,
        "photo_l1_first": photo[0] if photo else None,
        "photo_l1_last": photo[-1] if photo else None,
    })
    # timing goes to the manifest (the stage summary) only: outputs stay byte-identical
    summary["seconds"] = {"refine": round(t_refined - t_start, 3),
                          "write": round(time.perf_counter() - t_refined, 3)}
    ctx.progress("done", 1.0)
    return summary


STAGE = StageSpec("texture", Options, inputs, run, uses_model=frozenset({"input"}))
