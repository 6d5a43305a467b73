"""The ray-cast G-buffer, albedo shading and the rendering metrics, against analytic values."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from r2s.geometry.camera import pixel_rays
from r2s.io.input_scene import Camera
from r2s.metrics.rendering import (PSNR_CAP_DB, masked_psnr, masked_ssim, render_scene_rgb,
                                   rendering_metrics, side_by_side, side_by_side_png,
                                   error_colour_bar)
from r2s.render.gbuffer import interpolate, rasterize
from r2s.render.shade import MeshColour, shade
from r2s.render.texel import bilinear_footprint, sample

W, H = 160, 120
F = 100.0
K = np.array([[F, 0, 79.5], [0, F, 59.5], [0, 0, 1.0]])
CAM = np.eye(4)  # camera frame = world frame: x right, y down, z forward


def square(side_m: float, z_m: float, centre=(0.0, 0.0)) -> trimesh.Trimesh:
    """A square facing the camera (normal -z) at depth z_m."""
    h = side_m / 2
    cx, cy = centre
    v = np.array([[cx - h, cy - h, z_m], [cx + h, cy - h, z_m], [cx + h, cy + h, z_m],
                  [cx - h, cy + h, z_m]])
    return trimesh.Trimesh(v, [[0, 2, 1], [0, 3, 2]], process=False)


def test_square_silhouette_area_is_the_count_of_pixel_centres_inside_it():
    # side 0.3 m at 1 m: spans u in [79.5 - 15, 79.5 + 15] -> 30 centres per row and column
    gb = rasterize([square(0.3, 1.0)], K, CAM, W, H)
    assert int(gb.hit.sum()) == 30 * 30
    # a box 0.2 m wide seen at 0.8 m (front face z = 0.7): 28.57 px -> 28 or 29 centres
    box = trimesh.creation.box((0.2, 0.2, 0.2))
    box.apply_translation((0, 0, 0.8))
    gb = rasterize([box], K, CAM, W, H)
    analytic = (F * 0.2 / 0.7) ** 2
    assert abs(int(gb.hit.sum()) - analytic) <= 2 * 2 * F * 0.2 / 0.7  # within one pixel rim
    assert np.nanmax(gb.depth_m) == pytest.approx(0.7, abs=1e-5)


def test_depth_of_a_tilted_plane_matches_the_ray_plane_intersection():
    # plane through (0, 0, 1) with normal (0.3, -0.2, -1): z = 1 + (0.3 x - 0.2 y) / 1
    n = np.array([0.3, -0.2, -1.0])
    xs = np.linspace(-0.6, 0.6, 13)
    gx, gy = np.meshgrid(xs, xs)
    gz = 1.0 + (n[0] * gx + n[1] * gy) / -n[2]
    pts = np.stack([gx, gy, gz], -1).reshape(-1, 3)
    faces = []
    for r in range(12):
        for c in range(12):
            a = r * 13 + c
            faces += [[a, a + 13, a + 1], [a + 1, a + 13, a + 14]]
    plane = trimesh.Trimesh(pts, faces, process=False)
    gb = rasterize([plane], K, CAM, W, H)
    _, dirs = pixel_rays(K, CAM, W, H)  # camera-frame direction with z = 1
    # point = t * d with d_z = 1: n . (t d - p0) = 0 -> t = n . p0 / n . d
    t = (n @ np.array([0, 0, 1.0])) / (dirs @ n)
    hit = gb.hit
    assert hit.sum() > 0.5 * W * H
    np.testing.assert_allclose(gb.depth_m[hit], t[hit], atol=1e-5)
    # barycentric interpolation of the vertex positions gives the hit point
    pixels, xyz = interpolate(gb, 0, plane.faces, plane.vertices)
    expected = dirs[pixels[:, 0], pixels[:, 1]] * t[pixels[:, 0], pixels[:, 1], None]
    np.testing.assert_allclose(xyz, expected, atol=1e-5)


def test_nearer_of_two_overlapping_boxes_wins():
    near = trimesh.creation.box((0.2, 0.2, 0.1))
    near.apply_translation((-0.05, 0, 0.8))
    far = trimesh.creation.box((0.4, 0.4, 0.1))
    far.apply_translation((0.1, 0, 1.5))
    for order in ([near, far], [far, near]):
        gb = rasterize(order, K, CAM, W, H)
        near_index = order.index(near)
        # the image centre sees both boxes along its ray: the near one must win
        assert gb.object_index[60, 80] == near_index
        assert gb.depth_m[60, 80] == pytest.approx(0.75, abs=1e-5)
        # right of the near box only the far box is seen, at its front face
        u = int(79.5 + F * 0.2 / 1.45) + 2
        assert gb.object_index[60, u] == 1 - near_index
        assert gb.depth_m[60, u] == pytest.approx(1.45, abs=1e-5)
        assert (gb.object_index == near_index).sum() == pytest.approx(
            (F * 0.2 / 0.75) ** 2, rel=0.1)


def test_bilinear_lookup_of_a_linear_ramp_is_exact():
    size = 16
    cols = np.arange(size)
    tex = np.repeat(np.repeat(cols[None, :, None], size, axis=0), 3, axis=2).astype(np.float64)
    uv = np.array([[(3.25 + 0.5) / size, 0.5], [(10.0 + 0.5) / size, 0.2]])
    idx, w = bilinear_footprint(uv, size, size)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(sample(tex, idx, w)[:, 0], [3.25, 10.0], atol=1e-5)


def test_shade_vertex_colours_and_texture():
    sq = square(0.3, 1.0)
    gb = rasterize([sq], K, CAM, W, H)
    red = MeshColour(vertex_rgb=np.tile([1.0, 0.0, 0.0], (4, 1)))
    img = shade(gb, [sq.faces], [red], background_rgb=(0, 0, 1))
    assert np.allclose(img[gb.hit], [1, 0, 0]) and np.allclose(img[~gb.hit], [0, 0, 1])
    # a texture with a constant colour gives that colour wherever the UVs point
    uv = np.array([[0.1, 0.1], [0.9, 0.1], [0.9, 0.9], [0.1, 0.9]])
    green = MeshColour(uv=uv, texture=np.tile(np.float32([0, 0.5, 0]), (8, 8, 1)))
    img = shade(gb, [sq.faces], [green])
    assert np.allclose(img[gb.hit], [0, 0.5, 0], atol=1e-6)


def test_render_scene_rgb_of_a_coloured_mesh_and_its_id_map():
    sq = square(0.3, 1.0)
    sq.visual.vertex_colors = np.tile([255, 0, 0, 255], (4, 1)).astype(np.uint8)
    cam = Camera(K=K, world_from_camera=CAM, width=W, height=H)
    rgb, ids = render_scene_rgb([sq], cam, ids=[7])
    assert rgb.dtype == np.uint8 and rgb.shape == (H, W, 3)
    assert set(np.unique(ids)) == {0, 7}
    assert (ids == 7).sum() == 900
    assert np.all(rgb[ids == 7] == [255, 0, 0]) and np.all(rgb[ids == 0] == 0)


def test_masked_psnr_and_ssim_against_analytic_values():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (40, 50, 3)).astype(np.uint8)
    mask = np.zeros((40, 50), bool)
    mask[10:30, 10:40] = True
    b = a.astype(np.int32)
    b[mask] = np.clip(b[mask] + np.where(b[mask] > 127, -10, 10), 0, 255)  # |diff| = 10
    b[~mask] = 255 - b[~mask]  # outside the mask: ignored
    b = b.astype(np.uint8)
    assert masked_psnr(a, b, mask) == pytest.approx(20 * np.log10(255 / 10), abs=1e-9)
    assert masked_psnr(a, a, mask) == PSNR_CAP_DB
    assert masked_psnr(a, b, np.zeros_like(mask)) is None
    assert masked_ssim(a, a.copy(), mask) == pytest.approx(1.0, abs=1e-12)
    # constant images: SSIM is the luminance term alone, (2 mu_a mu_b + C1) / (mu_a^2 + mu_b^2 + C1)
    c1 = (0.01 * 255) ** 2
    flat_a = np.full((30, 30, 3), 100, np.uint8)
    flat_b = np.full((30, 30, 3), 120, np.uint8)
    expected = (2 * 100 * 120 + c1) / (100 ** 2 + 120 ** 2 + c1)
    assert masked_ssim(flat_a, flat_b, np.ones((30, 30), bool)) == pytest.approx(expected, abs=1e-9)
    # what lies outside the mask does not change the score
    c = b.copy()
    c[~mask] = 0
    assert masked_ssim(a, c, mask) == pytest.approx(masked_ssim(a, b, mask), abs=1e-12)


def test_rendering_metrics_report_lpips_as_null_with_a_reason(monkeypatch, tmp_path):
    monkeypatch.delenv("R2S_LPIPS_WEIGHTS", raising=False)
    a = np.full((20, 20, 3), 100, np.uint8)
    m = rendering_metrics(a, a, np.ones((20, 20), bool))
    assert m["lpips"] is None and "R2S_LPIPS_WEIGHTS" in m["lpips_reason"]
    assert m["psnr"] == PSNR_CAP_DB and m["ssim"] == pytest.approx(1.0)
    monkeypatch.setenv("R2S_LPIPS_WEIGHTS", str(tmp_path / "missing.pth"))
    m = rendering_metrics(a, a, np.ones((20, 20), bool))
    assert m["lpips"] is None and "no such file" in m["lpips_reason"]


def test_side_by_side_picture(tmp_path):
    from PIL import Image

    a = np.zeros((30, 40, 3), np.uint8)
    b = np.full((30, 40, 3), 128, np.uint8)
    mask = np.zeros((30, 40), bool)
    mask[5:25, 5:35] = True
    pic = side_by_side([a, b], ["observed", "rendered"], mask)
    assert pic.shape == (30, 120, 3)
    assert np.all(pic[20, 80 + 20] == [255, 255, 0])  # full-scale error, inside the mask
    side_by_side_png(a, b, tmp_path / "sbs.png", mask)
    bar = error_colour_bar(120)
    assert Image.open(tmp_path / "sbs.png").size == (120, 30 + bar.shape[0])
    written = np.asarray(Image.open(tmp_path / "sbs.png").convert("RGB"))
    np.testing.assert_array_equal(written[:30], pic)
    np.testing.assert_array_equal(written[30:], bar)


def test_texel_convention_matches_trimesh_uv_lookup():
    """u follows the image columns, v grows upwards (row 0 at v = 1), as trimesh reads it."""
    from PIL import Image

    size = 64
    rows, cols = np.mgrid[0:size, 0:size]
    tex = np.stack([cols / size, rows / size, np.zeros_like(rows, dtype=float)], -1)
    image = Image.fromarray(np.round(tex * 255).astype(np.uint8))
    uv = np.random.default_rng(0).uniform(0.1, 0.9, (200, 2))
    ours = sample(np.asarray(image, dtype=np.float64) / 255.0, *bilinear_footprint(uv, size, size))
    theirs = trimesh.visual.color.uv_to_color(uv, image)[:, :3] / 255.0
    np.testing.assert_allclose(ours[:, :2], theirs[:, :2], atol=1.5 / size)
