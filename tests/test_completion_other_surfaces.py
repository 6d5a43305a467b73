"""A completed object keeps no material where the camera saw another object's surface.

The footprint of a completion is the convex hull of its points: for an L-shaped block (or a
curved banana) lying on a plate, the hull spans plate the camera saw inside the L's corner.
Carving against the depth removes what lies in front of the plate by more than the sensor
margin, and leaves a layer within the margin, which hides the plate in a render. Pixels
deep inside another instance's mask say the camera saw that object there: in front of them
nothing of this object may lie (``carving.OTHER_MARGIN_M``), and a column whose top the camera
saw as the other object goes whole (``completion._drop_columns_seen_as_other``).
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy import ndimage

from helpers_init import SynthObject, pose, render_view
from r2s.geometry.camera import backproject, intrinsics, look_at
from r2s.geometry.carving import carve_view
from r2s.geometry.completion import complete_from_points
from r2s.geometry.point_cleanup import object_point_mask
from r2s.geometry.raycast import raycast_view

W, H = 320, 240
K = intrinsics(W, H, 45.0)
PLATE, ELL = 1, 2


def _ell() -> trimesh.Trimesh:
    """An L of two 120 x 30 mm arms, 25 mm tall, its corner at the origin's -x, -y side."""
    a = trimesh.creation.box((0.12, 0.03, 0.025))
    a.apply_translation((0.0, -0.045, 0.0))
    b = trimesh.creation.box((0.03, 0.12, 0.025))
    b.apply_translation((-0.045, 0.0, 0.0))
    return trimesh.util.concatenate([a, b])


def _scene():
    """(camera, depth with 1.5 mm noise, masks): the L on a 240 x 240 x 10 mm plate, seen
    from 40 degrees above, its open side (the plate inside its corner) facing the camera."""
    plate = trimesh.creation.box((0.24, 0.24, 0.01))
    objects = [SynthObject(PLATE, plate, pose([0.0, 0.0, 0.005])),
               SynthObject(ELL, _ell(), pose([0.0, 0.0, 0.0225]))]
    el, az = np.radians(40.0), np.radians(45.0)
    eye = 0.6 * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    camera = look_at(eye, (0.0, 0.0, 0.02))
    _, depth, masks = render_view(objects, K, camera, W, H)
    return camera, depth + np.random.default_rng(3).normal(0, 0.0015, depth.shape), masks


def _completed_ell(camera, depth, masks, other_inner_px: int) -> trimesh.Trimesh:
    pts, pix = backproject(depth, K, camera, masks == ELL, return_pixels=True)
    keep = object_point_mask(pts, pix, depth[pix[:, 0], pix[:, 1]], [0, 0, 0], [0, 0, 1])
    pts, pix = pts[keep], pix[keep]
    view = carve_view(K, camera, depth, pix, plane=(np.zeros(3), np.array([0.0, 0, 1])),
                      masks=masks, other_inner_px=other_inner_px)
    # extruded down to the table, through the plate, as the banana of the authors' demo
    # scene was (its base is not raised onto the plate)
    done = complete_from_points(pts, [0, 0, 0], [0, 0, 1], view=view)
    world = done.mesh.copy()
    world.apply_transform(done.world_from_object)
    return world


def _drawn(world: trimesh.Trimesh, camera, masks) -> tuple[float, float]:
    """Rendered with the true plate: (pixels where the completion hides the plate more than
    2 px inside the plate's mask, over the L's mask area; the completion's silhouette IoU
    against the L's mask)."""
    plate = trimesh.creation.box((0.24, 0.24, 0.01))
    plate.apply_translation((0.0, 0.0, 0.005))
    _, hit, _ = raycast_view([world, plate], K, camera, W, H)
    drawn, own = hit == 0, masks == ELL
    plate_inner = ndimage.binary_erosion(masks == PLATE, iterations=2)
    return (drawn & plate_inner).sum() / own.sum(), (drawn & own).sum() / (drawn | own).sum()


def test_an_l_on_a_plate_leaves_the_plate_it_spans_to_the_plate():
    """Measured: the completion hides the plate's inner pixels over 16 % of the L's mask
    area, silhouette IoU 0.78; with the sensor margin alone 31 %, IoU 0.70. What is left is
    the strip along the L's walls within the mask's uncertain rim (2 px) and 3 px of the
    plate's edge, where neither rule applies."""
    camera, depth, masks = _scene()
    assert (masks == ELL).sum() > 1500 and (masks == PLATE).sum() > 8000
    over, iou = _drawn(_completed_ell(camera, depth, masks, 3), camera, masks)
    over_margin, iou_margin = _drawn(_completed_ell(camera, depth, masks, 0), camera, masks)
    assert over <= 0.22, over
    assert over_margin >= 0.25, over_margin  # the layer within the sensor margin
    assert iou > iou_margin + 0.05, (iou, iou_margin)


def _ray_point(K_: np.ndarray, row: int, col: int, z_m: float) -> np.ndarray:
    """The world point (camera at the world origin) on pixel (row, col)'s ray at depth z_m."""
    depth = np.zeros((H, W))
    depth[row, col] = z_m
    one = np.zeros((H, W), bool)
    one[row, col] = True
    return backproject(depth, K_, np.eye(4), one)


def test_in_front_of_another_objects_surface_is_free_at_any_margin():
    """A flat view 1 m away, the left half this object's, the right half another's: 1 mm in
    front of the other's reading deep inside its mask is free (the sensor margin is 9 mm
    there); the same point within 3 px of the other's edge, or behind the reading, is not; a
    point within the margin behind the reading is seen as the other object, one 5 cm behind
    it is hidden by it."""
    from r2s.geometry.carving import seen_as_other, seen_free

    depth = np.ones((H, W))
    masks = np.where(np.arange(W)[None, :] < W // 2, ELL, PLATE).repeat(H, axis=0)
    own = np.argwhere(masks == ELL)
    tight = carve_view(K, np.eye(4), depth, own, masks=masks, other_inner_px=3)
    loose = carve_view(K, np.eye(4), depth, own, masks=masks, other_inner_px=0)
    deep = _ray_point(K, 120, 240, 0.999)
    edge = _ray_point(K, 120, W // 2 + 2, 0.999)  # 3 px into the other: within 3 px of its edge
    behind = _ray_point(K, 120, 240, 1.005)
    hidden = _ray_point(K, 120, 240, 1.05)
    assert seen_free(tight, deep)[0] and not seen_free(loose, deep)[0]
    assert not seen_free(tight, edge)[0]
    assert not seen_free(tight, behind)[0]
    assert seen_as_other(tight, behind)[0] and not seen_as_other(loose, behind)[0]
    assert not seen_as_other(tight, hidden)[0]
    assert not seen_as_other(tight, edge)[0]


def test_at_another_objects_outline_a_small_margin_carves():
    """The same flat view: at the other's pixels within 3 px of its edge (but outside this
    object's 2 px rim band) a point 3 mm in front of the reading is free once
    ``other_mask_margin_m`` = 2 mm is given, and not without it (the sensor margin there is
    9 mm); 1 mm in front is not free; in the rim band nothing is carved."""
    from r2s.geometry.carving import seen_free

    depth = np.ones((H, W))
    masks = np.where(np.arange(W)[None, :] < W // 2, ELL, PLATE).repeat(H, axis=0)
    own = np.argwhere(masks == ELL)
    with_any = carve_view(K, np.eye(4), depth, own, masks=masks, other_inner_px=3,
                          other_mask_margin_m=0.002)
    without = carve_view(K, np.eye(4), depth, own, masks=masks, other_inner_px=3)
    edge_3mm = _ray_point(K, 120, W // 2 + 2, 0.997)
    edge_1mm = _ray_point(K, 120, W // 2 + 2, 0.999)
    band_3mm = _ray_point(K, 120, W // 2 + 1, 0.997)  # within 2 px of the own mask
    assert seen_free(with_any, edge_3mm)[0] and not seen_free(without, edge_3mm)[0]
    assert not seen_free(with_any, edge_1mm)[0]
    assert not seen_free(with_any, band_3mm)[0]


def test_the_layer_over_the_plates_edge_is_thinner_with_the_mask_margin():
    """The L on the plate, carved with init's 1 px band: surface samples of the completion
    that project onto the plate more than 2 px from the L's mask and lie more than 3 mm in
    front of the plate's reading. Measured: 12 % of such samples with the sensor margin
    alone (the layer within 3 px of the plate's edge that ``other_inner_px`` leaves), 4.7 %
    with ``other_mask_margin_m`` = 2 mm (the rest: 1.5 mm depth noise and marching cubes
    between 2 mm grid nodes)."""
    from r2s.geometry.camera import image_pixels

    camera, depth, masks = _scene()
    pts, pix = backproject(depth, K, camera, masks == ELL, return_pixels=True)
    keep = object_point_mask(pts, pix, depth[pix[:, 0], pix[:, 1]], [0, 0, 0], [0, 0, 1])
    pts, pix = pts[keep], pix[keep]
    far = ~ndimage.binary_dilation(masks == ELL, iterations=2)

    def share_in_front(margin):
        view = carve_view(K, camera, depth, pix, plane=(np.zeros(3), np.array([0.0, 0, 1])),
                          masks=masks, other_inner_px=3, band_px=1,
                          other_mask_margin_m=margin)
        done = complete_from_points(pts, [0, 0, 0], [0, 0, 1], view=view)
        world = done.mesh.copy()
        world.apply_transform(done.world_from_object)
        samples = trimesh.sample.sample_surface_even(world, 100000, seed=0)[0]
        ok, row, col, _, z = image_pixels(samples, K, camera, H, W)
        on_plate = ok & (masks[row, col] == PLATE) & far[row, col]
        assert on_plate.sum() > 5000
        return float(np.mean(depth[row, col][on_plate] - z[on_plate] > 0.003))

    with_margin, without = share_in_front(0.002), share_in_front(None)
    assert without > 0.09, without
    assert with_margin < 0.07, with_margin
    assert with_margin < 0.5 * without, (with_margin, without)
