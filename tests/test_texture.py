"""UV atlases, baking, textured GLB round trips, photometric refinement and the texture stage."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from PIL import Image
from scipy import ndimage

from helpers_texture import (SynthObject, pose, render_view, table_camera, textured_object,
                             write_scene)
from r2s.geometry.camera import project, transform_points
from r2s.io.mesh_io import load_mesh, save_mesh
from r2s.io.state import read_state
from r2s.metrics.rendering import masked_psnr
from r2s.render.shade import mesh_colour
from r2s.runner.base import run_stage
from r2s.stages.texture import STAGE, Options
from r2s.texture.bake import bake_vertex_values, uv_raster
from r2s.texture.refine import RefineOptions, refine_textures, seen_texels
from r2s.texture.scene import observed_pixels, pixel_samples, render_textures, scene_gbuffer
from r2s.texture.textured import TexturedMesh, export_texture, textured_mesh, to_trimesh
from r2s.texture.uv import chart_atlas

torch.set_num_threads(1)


def uv_area(uv: np.ndarray, faces: np.ndarray) -> float:
    t = uv[faces]
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    return float(0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum())


def _noisy_sphere() -> trimesh.Trimesh:
    """A 5k-face sphere with 1 % radial noise (normals scatter by tens of degrees)."""
    s = trimesh.creation.icosphere(4, 0.05)
    noise = 1 + 0.01 * np.random.default_rng(0).standard_normal((len(s.vertices), 1))
    return trimesh.Trimesh(s.vertices * noise, s.faces, process=False)


@pytest.mark.parametrize("name", ["box", "sphere", "torus", "capsule", "noisy_sphere"])
def test_atlas_keeps_the_geometry_and_no_two_faces_share_texels(name):
    mesh = {
        "box": lambda: trimesh.creation.box((0.1, 0.05, 0.2)),
        "sphere": lambda: trimesh.creation.icosphere(3, 0.05),
        "torus": lambda: trimesh.creation.torus(0.1, 0.04),  # folds over itself along z
        "capsule": lambda: trimesh.creation.capsule(0.1, 0.03),
        "noisy_sphere": _noisy_sphere,
    }[name]()
    size = 256
    atlas = chart_atlas(mesh.vertices, mesh.faces, size, gutter_px=2)
    np.testing.assert_allclose(atlas.vertices[atlas.faces], mesh.vertices[mesh.faces], atol=0)
    assert atlas.uv.min() >= 0.0 and atlas.uv.max() <= 1.0
    # rasterised coverage equals the summed UV area only if no texel is claimed twice
    face, _ = uv_raster(atlas.uv, atlas.faces, size, size)
    covered = int((face >= 0).sum())
    area_texels = uv_area(atlas.uv, atlas.faces) * size * size
    assert covered == pytest.approx(area_texels, rel=0.03)
    assert area_texels > 0.2 * size * size  # the packing uses a fair share of the texture
    # charts are separated by the gutter: no texel next to a chart belongs to another chart
    chart_of_texel = np.where(face >= 0, atlas.chart[np.maximum(face, 0)], -1)
    for k in np.unique(atlas.chart):
        own = chart_of_texel == k
        ring = ndimage.binary_dilation(own, iterations=2) & ~own
        assert not np.any((chart_of_texel[ring] >= 0) & (chart_of_texel[ring] != k))


def test_baked_vertex_colours_follow_a_linear_colour_field():
    box = trimesh.creation.box((0.2, 0.2, 0.2))

    def field(p):
        return np.clip(0.5 + 2.0 * p @ np.array([[1, 0, 0], [0, 1, 0], [0.5, 0.5, 1]]).T, 0, 1)

    rgb = field(box.vertices)
    box.visual.vertex_colors = np.c_[np.round(rgb * 255), np.full(8, 255)].astype(np.uint8)
    tm = textured_mesh(box, texture_size=64)
    assert tm.origin == "vertex_colors" and tm.texture.shape == (64, 64, 3)
    face, bary = uv_raster(tm.uv, tm.faces, 64, 64)
    points = bake_vertex_values(face, bary, tm.faces, tm.vertices)
    covered = face >= 0
    np.testing.assert_allclose(tm.texture[covered], field(points[covered]), atol=1.0 / 255)
    # gutter texels copy a chart texel (no black seams at chart borders)
    chart_colours = {tuple(c) for c in tm.texture[covered]}
    assert all(tuple(c) in chart_colours for c in tm.texture[~covered])


def test_textured_glb_round_trips_with_its_texture():
    sphere = trimesh.creation.icosphere(2, 0.05)
    sphere.visual.vertex_colors = np.c_[np.round((sphere.vertices * 8 + 0.5).clip(0, 1) * 255),
                                        np.full(len(sphere.vertices), 255)].astype(np.uint8)
    tm = textured_mesh(sphere, texture_size=64)
    path = Path(pytest.importorskip("tempfile").mkdtemp()) / "t.glb"
    save_mesh(to_trimesh(tm.vertices, tm.faces, tm.uv, tm.texture), path)
    loaded = load_mesh(path)
    colour = mesh_colour(loaded)
    assert colour.textured
    np.testing.assert_allclose(loaded.vertices, tm.vertices, atol=1e-6)
    np.testing.assert_allclose(colour.uv, tm.uv, atol=1e-6)
    np.testing.assert_allclose(colour.texture, tm.texture, atol=0.5 / 255 + 1e-6)
    # read back as a textured source, the UVs and texture are kept as they are
    again = textured_mesh(loaded, texture_size=64)
    assert again.origin == "texture" and again.native is None
    np.testing.assert_allclose(again.texture, colour.texture, atol=1e-6)


def test_export_keeps_a_larger_source_texture_where_nothing_changed():
    rng = np.random.default_rng(0)
    native = rng.uniform(0, 1, (128, 128, 3)).astype(np.float32)
    box = trimesh.creation.box((0.1, 0.1, 0.1))
    atlas = chart_atlas(box.vertices, box.faces, 128)
    source = to_trimesh(atlas.vertices, atlas.faces, atlas.uv, native)
    tm = textured_mesh(source, texture_size=32)
    assert tm.texture.shape == (32, 32, 3) and tm.native.shape == (128, 128, 3)
    np.testing.assert_allclose(export_texture(tm, tm.texture), tm.native, atol=1e-6)
    brighter = export_texture(tm, np.clip(tm.texture + 0.1, 0, 1))
    assert brighter.shape == (128, 128, 3)
    inside = (tm.native < 0.85) & (tm.texture.mean() < 0.85)
    assert np.mean(brighter[inside] - tm.native[inside]) == pytest.approx(0.1, abs=0.02)


# ---- photometric refinement on a known scene ---------------------------------------------

W, H = 160, 120


def _box_scene(noise_sigma: float = 0.01) -> tuple[SynthObject, object]:
    box = trimesh.creation.box((0.12, 0.09, 0.08))
    obj = textured_object(1, box, pose((0, 0, 0.04), 0.5), texture_size=64, seed=3)
    K, world_from_camera = table_camera(W, H, distance_m=0.35, elevation_deg=40)
    view = render_view([obj], K, world_from_camera, W, H, noise_sigma=noise_sigma, seed=1)
    return obj, view


def _refine(obj: SynthObject, view, texture: np.ndarray, lambda_tv: float, iterations: int = 150,
            tv_on_change: bool = False):
    tm = TexturedMesh(obj.vertices, obj.faces, obj.uv, texture, None, "texture")
    gb = scene_gbuffer([tm], [obj.world_from_object], view.K, view.world_from_camera, W, H)
    region = observed_pixels(gb, view.masks, [obj.id], erode_px=0)[0]
    samples = pixel_samples(gb, 0, tm, region, view.rgb)
    result = refine_textures([texture], [samples], RefineOptions(
        iterations=iterations, lr=0.02, lambda_tv=lambda_tv), tv_reference=[tv_on_change])
    return tm, gb, samples, result.textures[0]


@pytest.fixture(scope="module")
def scrambled_runs():
    obj, view = _box_scene()
    rng = np.random.default_rng(7)
    flat = obj.texture.reshape(-1, 3)
    scrambled = flat[rng.permutation(len(flat))].reshape(obj.texture.shape)
    with_tv = _refine(obj, view, scrambled, lambda_tv=0.5)
    without_tv = _refine(obj, view, scrambled, lambda_tv=0.0)
    tv_on_change = _refine(obj, view, scrambled, lambda_tv=0.5, tv_on_change=True)
    return obj, view, scrambled, with_tv, without_tv, tv_on_change


def test_refinement_restores_the_psnr_of_a_scrambled_texture(scrambled_runs):
    obj, view, scrambled, (tm, gb, samples, refined), _, _ = scrambled_runs
    mask = view.masks > 0
    assert mask.sum() > 2000 and samples.count > 2000
    psnr_original = masked_psnr(view.rgb, render_textures(gb, [tm], [obj.texture]), mask)
    psnr_scrambled = masked_psnr(view.rgb, render_textures(gb, [tm], [scrambled]), mask)
    psnr_refined = masked_psnr(view.rgb, render_textures(gb, [tm], [refined]), mask)
    assert psnr_original > 38.0  # the 1 % noise
    assert psnr_scrambled < psnr_original - 15.0
    assert psnr_refined >= psnr_original - 1.0


def _unseen_interior(obj: SynthObject, samples, size: int) -> np.ndarray:
    """Texels inside charts that no pixel reads (box faces turned away from the camera)."""
    face, _ = uv_raster(obj.uv, obj.faces, size, size)
    seen = seen_texels(samples, (size, size))
    atlas = chart_atlas(obj.vertices, obj.faces, size)
    chart = np.where(face >= 0, atlas.chart[np.maximum(face, 0)], -1)
    unseen_charts = [k for k in np.unique(chart[chart >= 0]) if not seen[chart == k].any()]
    region = np.isin(chart, unseen_charts)
    return ndimage.binary_erosion(region, iterations=2)


def _gradient_magnitude(texture: np.ndarray) -> np.ndarray:
    dx = np.zeros_like(texture)
    dy = np.zeros_like(texture)
    dx[:, :-1] = texture[:, 1:] - texture[:, :-1]
    dy[:-1] = texture[1:] - texture[:-1]
    return np.sqrt((dx ** 2 + dy ** 2).sum(axis=-1))


def test_tv_leaves_unseen_texels_smooth(scrambled_runs):
    obj, view, scrambled, (_, _, samples, refined), (_, _, _, refined_no_tv), _ = scrambled_runs
    unseen = _unseen_interior(obj, samples, 64)
    assert unseen.sum() > 300  # the bottom and the far sides of the box
    g_scrambled = _gradient_magnitude(scrambled)[unseen].mean()
    g_refined = _gradient_magnitude(refined)[unseen].mean()
    g_no_tv = _gradient_magnitude(refined_no_tv)[unseen].mean()
    assert g_scrambled > 0.3
    assert g_refined < 0.05  # smooth: about 13 grey levels per texel at most on average
    assert g_no_tv == pytest.approx(g_scrambled, rel=0.02)  # no TV: nothing moves them


def test_tv_on_the_change_keeps_the_initial_pattern_of_unseen_texels(scrambled_runs):
    obj, view, scrambled, (_, _, samples, _), _, (_, _, _, refined) = scrambled_runs
    unseen = _unseen_interior(obj, samples, 64)
    change = refined - scrambled
    assert _gradient_magnitude(change)[unseen].mean() < 0.05  # the change is smooth ...
    assert _gradient_magnitude(refined)[unseen].mean() == pytest.approx(
        _gradient_magnitude(scrambled)[unseen].mean(), rel=0.1)  # ... the pattern stays


# ---- the stage ----------------------------------------------------------------------------

def _two_box_scene(tmp_path: Path) -> tuple[Path, list[SynthObject]]:
    """A red box in front of a larger blue box; init meshes are dark grey."""
    front = textured_object(1, trimesh.creation.box((0.06, 0.06, 0.06)), pose((0.0, -0.05, 0.03)),
                            64, 0)
    back = textured_object(2, trimesh.creation.box((0.16, 0.05, 0.10)), pose((0.0, 0.05, 0.05)),
                           64, 1)
    front.texture[:] = (0.85, 0.1, 0.1)
    back.texture[:] = (0.1, 0.2, 0.85)
    K, world_from_camera = table_camera(W, H, distance_m=0.4, elevation_deg=25)
    view = render_view([front, back], K, world_from_camera, W, H, noise_sigma=0.005)
    grey = [o.trimesh(np.full_like(o.texture, 0.15)) for o in (front, back)]
    return write_scene(tmp_path / "scene", [front, back], view, grey), [front, back]


def test_texture_stage_respects_occlusion_and_writes_textured_meshes(tmp_path):
    scene, (front, back) = _two_box_scene(tmp_path)
    options = Options(texture_size=64, iterations=150)
    result = run_stage(STAGE, scene, options)
    s = result.summary
    assert s["psnr_after"] > s["psnr_before"] + 10 and s["ssim_after"] > s["ssim_before"]
    state = read_state(scene / "texture")
    assert state.stage == "texture" and [o.id for o in state.objects] == [1, 2]
    np.testing.assert_allclose(state.object(2).pose, back.world_from_object)
    metrics = json.loads((scene / "texture" / "metrics.json").read_text())
    assert metrics["psnr_after"] == pytest.approx(s["psnr_after"])
    assert metrics["after"]["lpips"] is None and metrics["after"]["lpips_reason"]
    assert (scene / "texture" / "before_after.png").is_file()

    mesh = load_mesh(scene / "texture" / state.object(2).mesh)
    colour = mesh_colour(mesh)
    assert colour.textured
    # every texel of the back box: its world point, whether it faces the camera, and
    # whether the camera sees it or the front box hides it
    camera = json.loads((scene / "input" / "camera.json").read_text())
    world_from_camera = np.asarray(camera["world_from_camera"])
    face, bary = uv_raster(colour.uv, mesh.faces, 64, 64)
    face = face.reshape(-1)
    covered = face >= 0
    local = bake_vertex_values(face.reshape(64, 64), bary, mesh.faces, mesh.vertices)
    points = transform_points(back.world_from_object, local.reshape(-1, 3))
    normals = mesh.face_normals[np.maximum(face, 0)] @ back.world_from_object[:3, :3].T
    facing = np.einsum("nk,nk->n", normals, world_from_camera[:3, 3] - points) > 0
    uv_px, z = project(points, np.asarray(camera["K"]), world_from_camera)
    u = np.clip(np.round(uv_px[:, 0]), 0, W - 1).astype(int)
    v = np.clip(np.round(uv_px[:, 1]), 0, H - 1).astype(int)
    masks = np.asarray(Image.open(scene / "input" / "masks.png"))
    depth = np.load(scene / "input" / "depth.npy")[v, u]
    front_facing = covered & facing
    visible = front_facing & (masks[v, u] == 2) & (np.abs(z - depth) < 0.003)
    hidden = front_facing & (masks[v, u] == 1) & (z > depth + 0.005)
    assert hidden.sum() > 30 and visible.sum() > 100
    tex = colour.texture.reshape(-1, 3)
    assert tex[visible, 2].mean() > 0.7 and tex[visible, 0].mean() < 0.3  # seen: blue
    assert np.all(tex[hidden, 0] < 0.35)  # hidden by the red box: never painted red

    again = run_stage(STAGE, scene, options, force=False)
    assert not again.ran


@pytest.mark.slow
@pytest.mark.seed_demo
def test_texture_stage_on_the_peer_demo_scene_with_its_prior_textures(seed_demo):
    """ycb5: the priors (foundation-model textures, already posed) as the init state."""
    from r2s.io.input_scene import load_input

    scene = load_input(seed_demo)
    init = seed_demo / "init"
    objects = []
    for spec in scene.objects:
        save_mesh(load_mesh(spec.prior_mesh), init / "meshes" / f"{spec.id}.glb")
        objects.append({"id": spec.id, "label": spec.label, "mesh": f"meshes/{spec.id}.glb",
                        "world_from_object": spec.world_from_prior.tolist()})
    (init / "state.json").write_text(json.dumps({
        "stage": "init", "support": {"point": [0, 0, 0], "normal": [0, 0, 1]},
        "objects": objects}))
    (seed_demo / "manifest.json").write_text(json.dumps({"stages": {"init": {"status": "done"}}}))
    result = run_stage(STAGE, seed_demo, Options(texture_size=128, iterations=100))
    s = result.summary
    # the priors' shapes differ from the true ones, so silhouettes limit what texture can do
    assert s["psnr_after"] > s["psnr_before"] + 4.0
    assert s["ssim_after"] > s["ssim_before"] + 0.2
    metrics = json.loads((seed_demo / "texture" / "metrics.json").read_text())
    assert {o["texture_origin"] for o in metrics["objects"]} == {"texture"}
    # the 1024^2 prior textures are kept at their resolution
    assert all(o["texture_shape"] == [1024, 1024] for o in metrics["objects"])
