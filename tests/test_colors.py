"""Vertex colours from the image and the fit overlay, against a hand-made view."""

from __future__ import annotations

import numpy as np
import trimesh

from r2s.geometry.colors import color_mesh_from_image, has_appearance, visible_vertex_colors
from r2s.geometry.overlay import crop_box, fit_overlay

K = np.array([[100.0, 0, 49.5], [0, 100.0, 49.5], [0, 0, 1]])
CAM = np.array([[1.0, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 1.0], [0, 0, 0, 1]])  # looks down


def _image():
    rgb = np.zeros((100, 100, 3), np.uint8)
    rgb[:, :50] = (255, 0, 0)
    rgb[:, 50:] = (0, 0, 255)
    depth = np.full((100, 100), 0.9)
    return rgb, depth


def test_visible_vertices_take_their_pixel_colour():
    rgb, depth = _image()
    verts = np.array([[-0.1, 0.0, 0.1],    # left half, at the observed depth: red
                      [0.1, 0.0, 0.1],     # right half: blue
                      [0.1, 0.0, 0.0],     # 10 cm behind the observed surface: hidden
                      [2.0, 0.0, 0.1]])    # outside the image
    colors, seen = visible_vertex_colors(verts, rgb, depth, K, CAM)
    assert seen.tolist() == [True, True, False, False]
    assert colors[0].tolist() == [255, 0, 0] and colors[1].tolist() == [0, 0, 255]


def test_colour_mesh_fills_unseen_vertices_from_nearest_seen():
    rgb, depth = _image()
    box = trimesh.creation.box((0.3, 0.3, 0.1))  # top face at z = 0.05 in the object frame
    assert not has_appearance(box)
    coloured = color_mesh_from_image(box, np.array([[1.0, 0, 0, 0], [0, 1, 0, 0],
                                                    [0, 0, 1, 0.05], [0, 0, 0, 1]]),
                                     rgb, depth, K, CAM)
    assert has_appearance(coloured)
    vc = coloured.visual.vertex_colors[:, :3]
    left = coloured.vertices[:, 0] < 0
    assert (vc[left] == [255, 0, 0]).all() and (vc[~left] == [0, 0, 255]).all()


def test_overlay_outlines_and_crop():
    rgb, _ = _image()
    masks = np.zeros((100, 100), np.int32)
    masks[40:60, 40:60] = 3
    rendered = np.where(masks == 3, 0, -1)
    out = fit_overlay(rgb, rendered, masks, [3])
    assert out.shape == (100, 100, 3)
    assert (out[40, 45] == 255).all()                      # observed outline: white
    assert not (out[50, 45] == rgb[50, 45]).all()          # tinted inside
    assert (out[10, 10] == rgb[10, 10]).all()              # untouched outside
    assert crop_box([masks > 0]) == (30, 70, 30, 70)
    zoomed = fit_overlay(rgb, rendered, masks, [3], zoom_to_px=160)
    assert zoomed.shape == (160, 160, 3)
