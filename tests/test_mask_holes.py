"""Mask pixels without a depth reading take the depth of the object's nearest kept point
(r2s/geometry/mask_holes.py): exact on a plane facing the camera, limited to a radius, and
what it gives a completion seen through a sensor that loses the outline and dark pixels."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from helpers_init import SynthObject, pose, render_view, rotation
from r2s.geometry.camera import backproject, intrinsics, look_at
from r2s.geometry.carving import carve_view
from r2s.geometry.completion import complete_from_points
from r2s.geometry.mask_holes import fill_mask_holes
from r2s.geometry.point_cleanup import object_point_mask
from r2s.geometry.raycast import raycast_view
import trimesh

W, H = 320, 240
K = intrinsics(W, H, 45.0)


def test_holes_on_a_plane_facing_the_camera_lie_on_it_and_only_within_reach():
    """A square at 0.5 m facing the camera, its outer 2-pixel ring and a disc inside without
    depth, and a 20-pixel strip cut off from the readings: every hole within 6 px of a
    reading comes back at exactly 0.5 m on its own pixel's ray; the strip's far pixels
    (more than 6 px from any reading) stay empty."""
    depth = np.full((H, W), np.nan)
    mask = np.zeros((H, W), dtype=bool)
    mask[60:180, 80:200] = True
    mask[60:180, 200:220] = True  # a strip with no reading at all
    depth[62:178, 82:198] = 0.5
    depth[100:110, 120:130] = np.nan  # a dark patch inside
    camera = np.eye(4)
    kept = np.argwhere(np.isfinite(depth) & mask)
    points, pixels = fill_mask_holes(mask, depth, kept, K, camera, radius_px=6)

    holes = mask & ~np.isfinite(depth)
    dist = ndimage.distance_transform_edt(~(np.isfinite(depth) & mask))
    expected = holes & (dist <= 6)
    got = np.zeros_like(mask)
    got[pixels[:, 0], pixels[:, 1]] = True
    assert np.array_equal(got, expected)
    assert np.allclose(points[:, 2], 0.5, atol=1e-12)
    # each point on its own pixel's ray: it projects back onto that pixel
    uv = (K @ points.T).T
    assert np.allclose(uv[:, 0] / uv[:, 2], pixels[:, 1], atol=1e-9)
    assert np.allclose(uv[:, 1] / uv[:, 2], pixels[:, 0], atol=1e-9)
    assert not got[:, 205:220].any()  # 6+ px past the last reading


def test_nothing_to_fill_from_gives_no_points():
    mask = np.ones((10, 10), dtype=bool)
    depth = np.full((10, 10), np.nan)
    points, pixels = fill_mask_holes(mask, depth, np.zeros((0, 2), int), K, np.eye(4))
    assert points.shape == (0, 3) and pixels.shape == (0, 2)
    points, _ = fill_mask_holes(mask, np.full((10, 10), 0.5), np.argwhere(mask), K, np.eye(4),
                                radius_px=0)
    assert len(points) == 0


BOX = trimesh.creation.box((0.12, 0.08, 0.09))
BOX_POSE = pose([0.0, 0.0, 0.045], rotation([0, 0, 1], 25.0))


def _oblique_box_with_lost_depth(elevation_deg: float):
    """A box seen from ``elevation_deg`` above the table at 0.6 m, as a RealSense-class
    sensor reads it: no depth on the mask's outer 2-pixel band (the depth edge) nor on half
    of its other pixels (a dark surface)."""
    el, az = np.radians(elevation_deg), np.radians(-70.0)
    target = np.array([0.0, 0.0, 0.04])
    camera = look_at(target + 0.6 * np.array([np.cos(el) * np.cos(az),
                                              np.cos(el) * np.sin(az), np.sin(el)]), target)
    _, depth, masks = render_view([SynthObject(1, BOX, BOX_POSE)], K, camera, W, H)
    depth = depth + np.random.default_rng(0).normal(0, 0.0015, depth.shape)
    mask = masks == 1
    edge = mask & ~ndimage.binary_erosion(mask, iterations=2)
    dark = mask & (np.random.default_rng(1).random(mask.shape) < 0.5)
    depth[edge | dark] = np.nan
    return camera, depth, mask


def _complete_box(camera, depth, mask, fill_px: float):
    pts, pix = backproject(depth, K, camera, mask, return_pixels=True)
    keep = object_point_mask(pts, pix, depth[pix[:, 0], pix[:, 1]], [0, 0, 0], [0, 0, 1])
    pts, pix = pts[keep], pix[keep]
    filled, _ = fill_mask_holes(mask, depth, pix, K, camera, fill_px)
    margin = 0.25 * float(np.median(depth[pix[:, 0], pix[:, 1]])) / K[0, 0]
    done = complete_from_points(np.concatenate([pts, filled]), [0, 0, 0], [0, 0, 1],
                                hull_margin_m=margin, view=carve_view(K, camera, depth, pix))
    world = done.mesh.copy()
    world.apply_transform(done.world_from_object)
    hit_depth, _, _ = raycast_view([world], K, camera, W, H)
    seen = np.isfinite(hit_depth)
    return world, float((seen & mask).sum()) / float((seen | mask).sum())


@pytest.mark.parametrize("elevation_deg", [30.0, 50.0])
def test_a_box_whose_outline_and_dark_pixels_read_no_depth_keeps_its_footprint(
        elevation_deg: float):
    """The box of the oblique-view test with its depth edge and half of its pixels lost:
    with the holes filled its horizontal extents are within 7 % of the truth (measured: 5.4 % short at 30 deg, 1.9 % at 50) and its
    silhouette IoU against the mask is >= 0.93; from the readings alone the footprint
    falls short by more than 9 % (measured: 10-11 %) and the IoU stays under 0.9 (measured: 0.88)."""
    camera, depth, mask = _oblique_box_with_lost_depth(elevation_deg)
    truth = BOX.copy()
    truth.apply_transform(BOX_POSE)
    world, iou = _complete_box(camera, depth, mask, fill_px=6)
    short = 1.0 - world.extents[:2] / truth.extents[:2]
    assert np.abs(short).max() < 0.07, (world.extents, truth.extents)
    assert iou >= 0.93
    bare, bare_iou = _complete_box(camera, depth, mask, fill_px=0)
    assert (1.0 - bare.extents[:2] / truth.extents[:2]).max() > 0.09
    assert bare_iou < 0.9


def _plane_depth(height_m: float, camera: np.ndarray) -> np.ndarray:
    """(H, W) camera-z depth of the horizontal plane z = height_m (world), NaN where the
    ray does not fall onto it."""
    rows, cols = np.mgrid[0:H, 0:W].astype(np.float64)
    rays = np.stack([(cols - K[0, 2]) / K[0, 0], (rows - K[1, 2]) / K[1, 1],
                     np.ones_like(cols)], axis=-1) @ camera[:3, :3].T
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (height_m - camera[2, 3]) / rays[..., 2]
    return np.where(z > 0, z, np.nan)


@pytest.mark.parametrize("elevation_deg", [30.0, 50.0])
def test_height_rule_puts_the_unread_far_edge_of_a_level_top_on_it(elevation_deg):
    """The level top of a box (z = 60 mm) seen obliquely, its far 8 rows (the top of its
    silhouette) unread, as a sensor loses a grazing far edge. With the support plane, the
    filled points lie on the top face itself (|z - 0.06| < 1e-9 m), on their own rays, and
    behind the nearest reading; the nearest reading's depth would put them up to
    8 px * z / f above it. Holes in the near rows (the lower outline) keep the nearest
    reading's depth under both rules."""
    e = np.radians(elevation_deg)
    camera = look_at(np.array([-0.6 * np.cos(e), 0.0, 0.6 * np.sin(e)]), np.zeros(3))
    depth = _plane_depth(0.06, camera)
    mask = np.zeros((H, W), dtype=bool)
    mask[90:150, 120:200] = True
    depth[~mask] = np.nan
    depth[90:98, 120:200] = np.nan     # far edge: the top rows of the image
    depth[146:150, 120:200] = np.nan   # near edge: the bottom rows
    kept = np.argwhere(np.isfinite(depth))
    by_height, px = fill_mask_holes(mask, depth, kept, K, camera, radius_px=8,
                                    up=np.array([0.0, 0.0, 1.0]))
    by_depth, px_d = fill_mask_holes(mask, depth, kept, K, camera, radius_px=8)
    assert np.array_equal(px, px_d)
    far, near = px[:, 0] < 98, px[:, 0] >= 146
    assert far.sum() == 8 * 80 and near.sum() == 4 * 80
    assert np.abs(by_height[far, 2] - 0.06).max() < 1e-9
    assert (by_depth[far, 2] - 0.06).max() > 5 * 0.6 / K[0, 0] * 0.5  # the old rule: above
    assert np.allclose(by_height[near], by_depth[near], atol=1e-12)
    cam_points = (by_height - camera[:3, 3]) @ camera[:3, :3]
    uv = (K @ cam_points.T).T
    assert np.allclose(uv[:, 0] / uv[:, 2], px[:, 1], atol=1e-6)
    assert np.allclose(uv[:, 1] / uv[:, 2], px[:, 0], atol=1e-6)
