"""Objects cut by the image border are completed beyond it (geometry/border_extension.py).

Known answers from the hand-made scene of ``helpers_diagnose`` (exact depth, 320 x 240),
its image cropped so that the border cuts an object: a ball of radius 35 mm cut through its
middle, and a 200 x 30 x 30 mm bar crossing the border at a slant.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from helpers_diagnose import render
from r2s.geometry.border_extension import border_cap_points, border_cuts
from r2s.geometry.camera import backproject, intrinsics, look_at
from r2s.geometry.completion import complete_from_points
from r2s.geometry.raycast import raycast_view

UP = np.array([0.0, 0.0, 1.0])
ORIGIN = np.zeros(3)


def _cropped_points(depth, masks, K, world_from_camera, obj_id, first_col):
    """The object's points and pixels in the image with columns < ``first_col`` cut away."""
    depth = np.where(depth > 0, depth, np.nan)[:, first_col:]
    masks = masks[:, first_col:]
    K = K.copy()
    K[0, 2] -= first_col
    pts, pix = backproject(depth, K, world_from_camera, masks == obj_id, return_pixels=True)
    return pts, pix, K, depth.shape


def _completed(pts, pix, K, world_from_camera, shape, extend: bool) -> trimesh.Trimesh:
    cap = np.zeros((0, 3))
    if extend:
        cap, _ = border_cap_points(pts, pix, K, world_from_camera, shape[1], shape[0],
                                   ORIGIN, UP)
    done = complete_from_points(np.concatenate([pts, cap]), ORIGIN, UP)
    return done.mesh.copy().apply_transform(done.world_from_object)


def test_a_ball_cut_through_its_middle_is_completed_whole():
    r = render(noise_m=0.0)
    ball_id, radius = 4, 0.035
    centre = r["objects"][3][2][:3, 3]  # the ball's centre (it rests on z = 0)
    cols = np.nonzero(r["masks"] == ball_id)[1]
    # the column where the ball's centre projects: the cut runs through its middle
    cam = np.linalg.inv(r["world_from_camera"])
    c = cam[:3, :3] @ centre + cam[:3, 3]
    first_col = int(round(r["K"][0, 0] * c[0] / c[2] + r["K"][0, 2]))
    assert cols.min() < first_col < cols.max()
    pts, pix, K, shape = _cropped_points(r["depth"], r["masks"], r["K"], r["world_from_camera"],
                                         ball_id, first_col)
    cuts = border_cuts(pts, pix, K, r["world_from_camera"], np.eye(4), shape[1], shape[0])
    assert [c.side for c in cuts] == ["left"]
    true_volume = 4.0 / 3.0 * np.pi * radius ** 3
    true_centre = centre
    cut_off = _completed(pts, pix, K, r["world_from_camera"], shape, extend=False)
    whole = _completed(pts, pix, K, r["world_from_camera"], shape, extend=True)
    # without the extension the ball ends at the border: well under its volume, its centre
    # pulled into the image; with it, within 30 % and 10 mm
    assert cut_off.volume < 0.75 * true_volume
    assert whole.volume == pytest.approx(true_volume, rel=0.3)
    # measured: volume 0.45 -> 0.93 of the ball's, box centre 13.7 -> 7.5 mm from its centre
    # (the far side, which the camera does not see, is short either way)
    assert np.linalg.norm(whole.bounds.mean(axis=0) - true_centre) < 0.010
    assert np.linalg.norm(whole.bounds.mean(axis=0) - true_centre) \
        < 0.6 * np.linalg.norm(cut_off.bounds.mean(axis=0) - true_centre)


def test_a_bar_crossing_the_border_at_a_slant_continues_along_its_axis():
    bar = trimesh.creation.box((0.2, 0.03, 0.03))
    yaw = np.radians(30.0)
    pose = np.eye(4)
    pose[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
    pose[:3, 3] = [0.0, 0.0, 0.015]
    table = trimesh.creation.box((1.2, 1.2, 0.02))
    table.apply_translation([0.0, 0.0, -0.01])
    K = intrinsics(320, 240, 50.0)
    world_from_camera = look_at([0.05, -0.45, 0.4], [0.0, 0.0, 0.0])
    depth, index, _ = raycast_view([bar.copy().apply_transform(pose), table], K,
                                   world_from_camera, 320, 240)
    masks = np.where(index == 0, 1, 0).astype(np.int32)
    cols = np.nonzero(masks)[1]
    first_col = int(cols.min() + 0.4 * (cols.max() - cols.min()))  # 40 % of it cut away
    pts, pix, K2, shape = _cropped_points(depth, masks, K, world_from_camera, 1, first_col)
    axis = pose[:2, 0]
    seen = pts[:, :2] @ axis
    mesh = _completed(pts, pix, K2, world_from_camera, shape, extend=True)
    along = mesh.vertices[:, :2] @ axis
    across = mesh.vertices[:, :2] @ np.array([-axis[1], axis[0]])
    # it reaches farther along its axis than was seen, and stays a bar: no wider than
    # 1.5 times its 30 mm (a mirror image about the border would make a V)
    assert along.min() < seen.min() - 0.02
    assert np.ptp(across) < 0.045
    cut_off = _completed(pts, pix, K2, world_from_camera, shape, extend=False)
    assert np.ptp(cut_off.vertices[:, :2] @ axis) < np.ptp(along) - 0.02


def test_an_object_inside_the_image_gets_nothing():
    r = render(noise_m=0.0)
    pts, pix = backproject(np.where(r["depth"] > 0, r["depth"], np.nan), r["K"],
                           r["world_from_camera"], r["masks"] == 4, return_pixels=True)
    cap, src = border_cap_points(pts, pix, r["K"], r["world_from_camera"], 320, 240,
                                 ORIGIN, UP)
    assert cap.shape == (0, 3) and src.shape == (0,)


def test_the_extension_does_not_swallow_a_neighbour_seen_beside_the_cut():
    r = render(noise_m=0.0)
    ball_id = 4
    centre = r["objects"][3][2][:3, 3]
    cam = np.linalg.inv(r["world_from_camera"])
    c = cam[:3, :3] @ centre + cam[:3, 3]
    first_col = int(round(r["K"][0, 0] * c[0] / c[2] + r["K"][0, 2]))
    pts, pix, K, shape = _cropped_points(r["depth"], r["masks"], r["K"], r["world_from_camera"],
                                         ball_id, first_col)
    cap, _ = border_cap_points(pts, pix, K, r["world_from_camera"], shape[1], shape[0],
                               ORIGIN, UP)
    assert len(cap) > 0
    # a neighbour's points where the extension's middle would go
    neighbour = np.repeat(cap.mean(axis=0, keepdims=True), 20, axis=0)
    held, _ = border_cap_points(pts, pix, K, r["world_from_camera"], shape[1], shape[0],
                                ORIGIN, UP, others_world=neighbour)
    from scipy.spatial import Delaunay

    if len(held):
        covered = Delaunay(np.concatenate([pts, held])[:, :2]).find_simplex(neighbour[:, :2])
        assert np.all(covered < 0)
    assert len(held) < len(cap)
