"""Observation metrics (r2s.metrics.observation) on hand-made scenes with known answers.

The camera looks straight down from 1 m above the origin (f = 500 px). A thin slab
(1 mm) whose top face spans whole pixels renders exactly the pixels whose centres lie over
it, so its silhouette, shifted silhouettes and free-space violations are known exactly.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from r2s.metrics.observation import (free_space_map, observation_picture, observe_scene,
                                     pose_displacement, render_objects, silhouette_iou,
                                     unilateral_chamfer_m)
from r2s.render.gbuffer import rasterize

W, H, F = 160, 120, 500.0
K = np.array([[F, 0.0, 79.5], [0.0, F, 59.5], [0.0, 0.0, 1.0]])
CAMERA = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 1.0],
                   [0.0, 0.0, 0.0, 1.0]])
"""world_from_camera: at (0, 0, 1), looking down; image u along +x, v along -y."""


def slab(u0: int, u1: int, v0: int, v1: int, top_z: float, shift_px: float = 0.0,
         thickness_m: float = 0.001) -> trimesh.Trimesh:
    """A slab whose top face (at world height ``top_z``) covers pixels u0..u1 x v0..v1
    (inclusive) exactly, moved ``shift_px`` pixels along +u."""
    depth = 1.0 - top_z
    x0 = (u0 - 0.5 - K[0, 2] + shift_px) * depth / F
    x1 = (u1 + 0.5 - K[0, 2] + shift_px) * depth / F
    y1 = -(v0 - 0.5 - K[1, 2]) * depth / F
    y0 = -(v1 + 0.5 - K[1, 2]) * depth / F
    box = trimesh.creation.box(extents=[x1 - x0, y1 - y0, thickness_m])
    box.apply_translation([(x0 + x1) / 2, (y0 + y1) / 2, top_z - thickness_m / 2])
    return box


def mask_of(u0: int, u1: int, v0: int, v1: int, obj_id: int = 1) -> np.ndarray:
    m = np.zeros((H, W), dtype=np.int32)
    m[v0:v1 + 1, u0:u1 + 1] = obj_id
    return m


def test_render_matches_mask_exactly():
    mesh = slab(40, 79, 30, 69, top_z=0.2)
    r = render_objects([mesh], [1], K, CAMERA, W, H)
    per, pooled = silhouette_iou(r.ids, mask_of(40, 79, 30, 69), [1])
    assert per[1] == pytest.approx(1.0, abs=1e-9)
    assert pooled == pytest.approx(1.0, abs=1e-9)
    assert np.nanmax(np.abs(r.depth_m[r.ids == 1] - 0.8)) < 1e-5


@pytest.mark.parametrize("k", [1, 3, 10])
def test_shifted_render_has_known_iou(k):
    width = 40  # pixels 40..79
    mesh = slab(40, 79, 30, 69, top_z=0.2, shift_px=k)
    r = render_objects([mesh], [1], K, CAMERA, W, H)
    per, _ = silhouette_iou(r.ids, mask_of(40, 79, 30, 69), [1])
    assert per[1] == pytest.approx((width - k) / (width + k), abs=1e-9)


def test_pooled_iou_sums_over_objects_and_occlusion_counts():
    # object 2 lies below object 1 and is half hidden by it in the render, as in the mask
    top = slab(40, 79, 30, 69, top_z=0.2)
    below = slab(60, 99, 30, 69, top_z=0.1)
    masks = mask_of(60, 99, 30, 69, 2)
    masks[30:70, 40:80] = 1
    r = render_objects([top, below], [1, 2], K, CAMERA, W, H)
    per, pooled = silhouette_iou(r.ids, masks, [1, 2])
    assert per[1] == pytest.approx(1.0) and per[2] == pytest.approx(1.0)
    # now the mask says object 2 is fully visible (40 x 40) but the render shows 20 x 40
    masks2 = mask_of(60, 99, 30, 69, 2)
    masks2[30:70, 40:60] = 1
    per, pooled = silhouette_iou(r.ids, masks2, [1, 2])
    assert per[1] == pytest.approx(20 / 40)            # rendered 40 wide, mask 20 wide
    assert per[2] == pytest.approx(20 / 40)            # rendered 20 wide, mask 40 wide
    assert pooled == pytest.approx((800 + 800) / (1600 + 1600))


def test_free_space_fraction_is_analytic():
    # rendered 40 x 40 px at depth 0.8 over a table seen at depth 1.0; the mask is the
    # left 20 columns. Columns more than 2 px right of the mask (u >= 62) violate.
    mesh = slab(40, 79, 30, 69, top_z=0.2)
    masks = mask_of(40, 59, 30, 69)
    depth = np.full((H, W), 1.0)
    depth[masks == 1] = 0.8
    r = render_objects([mesh], [1], K, CAMERA, W, H)
    fs = free_space_map(r, depth, masks, 1)
    assert int(fs.sum()) == 18 * 40
    expected = np.zeros((H, W), bool)
    expected[30:70, 62:80] = True
    assert np.array_equal(fs, expected)
    assert fs.sum() / (masks == 1).sum() == pytest.approx(0.9)
    # no reading in the top 10 rows, and 10 mm behind only (< 15 mm margin) in the next 10
    depth[30:40, 60:] = np.nan
    depth[40:50, 60:] = 0.81
    fs = free_space_map(r, depth, masks, 1)
    assert int(fs.sum()) == 18 * 20
    scene = observe_scene([mesh], [1], K, CAMERA, depth, masks)
    assert scene.objects[0].free_space_violation == pytest.approx(18 * 20 / 800)
    assert scene.violation_map.sum() == 18 * 20


def test_object_behind_observed_surface_is_not_a_violation():
    # the render lies behind what the camera saw (an occluder): says nothing
    mesh = slab(40, 79, 30, 69, top_z=0.2)
    masks = mask_of(40, 59, 30, 69)
    depth = np.full((H, W), 0.5)
    r = render_objects([mesh], [1], K, CAMERA, W, H)
    assert not free_space_map(r, depth, masks, 1).any()


def test_ucd_of_points_on_and_off_the_surface():
    box = trimesh.creation.box(extents=[0.1, 0.06, 0.04])
    box.apply_translation([0.02, -0.01, 0.3])
    pts, faces = trimesh.sample.sample_surface(box, 5000, seed=3)
    assert unilateral_chamfer_m(pts, box) < 1e-6
    for d in (0.002, 0.01):
        off = pts + d * box.face_normals[faces]
        assert unilateral_chamfer_m(off, box) == pytest.approx(d, abs=2e-6)
    assert unilateral_chamfer_m(np.zeros((0, 3)), box) is None


def test_ucd_through_backprojection_of_a_rendered_depth():
    box = trimesh.creation.box(extents=[0.08, 0.05, 0.05])
    box.apply_translation([0.01, 0.0, 0.025])
    g = rasterize([box], K, CAMERA, W, H)
    depth = g.depth_m.astype(np.float64)
    masks = np.where(g.object_index == 0, 3, 0).astype(np.int32)
    scene = observe_scene([box], [3], K, CAMERA, depth, masks)
    o = scene.objects[0]
    assert o.iou == pytest.approx(1.0)
    assert o.ucd_mm < 0.01
    assert o.free_space_violation == 0.0
    moved = box.copy().apply_translation([0.0, 0.0, -0.004])  # 4 mm lower: seen 4 mm off
    o = observe_scene([moved], [3], K, CAMERA, depth, masks).objects[0]
    assert 3.0 < o.ucd_mm <= 4.0 + 1e-3


def test_pose_displacement():
    a = np.eye(4)
    b = np.eye(4)
    b[:3, 3] = [0.03, 0.04, 0.0]
    assert pose_displacement(a, b, np.zeros(3)) == pytest.approx((0.05, 0.0), abs=1e-12)
    c = np.eye(4)
    ang = np.radians(30.0)
    c[:2, :2] = [[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]]
    m, deg = pose_displacement(a, c, np.array([0.1, 0.0, 0.0]))
    assert deg == pytest.approx(30.0, abs=1e-9)
    assert m == pytest.approx(2 * 0.1 * np.sin(ang / 2), abs=1e-12)


def test_picture_paints_violations_red_and_keeps_size():
    mesh = slab(40, 79, 30, 69, top_z=0.2)
    masks = mask_of(40, 59, 30, 69)
    depth = np.full((H, W), 1.0)
    scene = observe_scene([mesh], [1], K, CAMERA, depth, masks)
    rgb = np.full((H, W, 3), 100, np.uint8)
    pic = observation_picture(rgb, scene.rendered.ids, scene.violation_map, masks,
                              {1: (0.0, 0.0, 1.0)}, "caption")
    assert pic.shape == (H + 18, W, 3)
    assert tuple(pic[50, 75]) == (255, 0, 0)
    assert tuple(pic[5, 5]) == (60, 60, 60)  # untouched background is dimmed to 60 %


def test_an_instance_without_an_object_counts_as_a_miss():
    """Two instances of 40 x 40 and 20 x 10 px, the first rendered exactly and the second
    not reconstructed: it is reported missing with IoU 0, and the pooled IoU is
    1600 / (1600 + 200) instead of 1.0 (the worst IoU stays the first's: the second mask
    is under 1,000 px)."""
    masks = mask_of(40, 79, 30, 69) + mask_of(100, 119, 30, 39, obj_id=2)
    depth = np.full((H, W), 1.0)
    scene = observe_scene([slab(40, 79, 30, 69, top_z=0.2)], [1], K, CAMERA, depth, masks,
                          mask_ids=[1, 2])
    lost = scene.objects[-1]
    assert (lost.id, lost.missing, lost.iou, lost.mask_px, lost.rendered_px) == (2, True, 0.0,
                                                                               200, 0)
    assert scene.pooled_iou == pytest.approx(1600 / 1800, abs=1e-12)
    summary = scene.summary()
    assert summary["missing_objects"] == 1 and scene.missing_ids == [2]
    assert summary["min_silhouette_iou"] == pytest.approx(1.0)
    # without the view's ids the lost instance is not seen: the old, flattering score
    assert observe_scene([slab(40, 79, 30, 69, top_z=0.2)], [1], K, CAMERA, depth,
                         masks).pooled_iou == pytest.approx(1.0)


def test_an_object_that_lost_most_of_its_mask_since_init_is_flagged():
    """Two slabs seen exactly where they lie (IoU 1 at the init pose), then both moved 6 px
    (9.6 mm at 0.8 m, under the 20 mm displacement tolerance). The 10 x 10 px one keeps
    4 x 10 of its 100 px: IoU 40 / 160 = 0.25, under half of 1, flagged; the 60 x 60 px one
    keeps 54 x 60: IoU 3240 / 3960 = 0.818, not flagged. A third, lower slab (8 x 10 px)
    that did not move is now hidden but for 2 of its 8 columns by the small one moved over
    it: IoU 0.25, but its own move cost it nothing (``iou_seen`` 0.25 too), not flagged."""
    from r2s.metrics.observation_check import FlagTolerances, check_observation

    small, large = slab(20, 29, 20, 29, top_z=0.2), slab(70, 129, 30, 89, top_z=0.2)
    low = slab(30, 37, 20, 29, top_z=0.1)
    masks = mask_of(20, 29, 20, 29, 1) + mask_of(70, 129, 30, 89, 2) + mask_of(30, 37, 20, 29, 3)
    depth = np.where(masks == 3, 0.9, np.where(masks > 0, 0.8, 1.0))
    shift = np.eye(4)
    shift[0, 3] = 6 * 0.8 / F
    moved = [m.copy().apply_transform(shift) for m in (small, large)] + [low]
    check = check_observation(moved, [1, 2, 3], K, CAMERA, depth, masks,
                              world_from_object={1: shift, 2: shift, 3: np.eye(4)},
                              init_world_from_object={i: np.eye(4) for i in (1, 2, 3)},
                              centres_in_object={1: small.centroid, 2: large.centroid,
                                                 3: low.centroid},
                              tolerances=FlagTolerances(max_free_space=10.0))
    blocks = check.blocks
    assert blocks[1]["iou_seen"] == pytest.approx(1.0, abs=1e-9)
    assert blocks[1]["iou"] == pytest.approx(0.25, abs=1e-9)
    assert blocks[1]["displacement_m"] == pytest.approx(0.0096, abs=1e-6)
    assert blocks[1]["flagged"]
    assert "fell from 1.00 where it was seen to 0.25" in blocks[1]["reason"]
    assert blocks[2]["iou"] == pytest.approx(3240 / 3960, abs=1e-4)  # rounded to 4 digits
    assert not blocks[2]["flagged"]
    assert blocks[3]["iou"] == pytest.approx(0.25, abs=1e-9)
    assert blocks[3]["iou_seen"] == pytest.approx(0.25, abs=1e-9)
    assert not blocks[3]["flagged"]


@pytest.mark.parametrize("min_iou_kept, flagged", [(0.75, True), (0.5, False)])
def test_an_object_that_lost_a_third_of_its_mask_is_flagged_at_the_default(min_iou_kept,
                                                                            flagged):
    """A 30 x 30 px slab moved 6 px keeps 24 x 30 of its 900 px: IoU 720 / 1080 = 0.667 of
    the 1.0 it has where it was seen. Under the default share kept (0.75) it is flagged; the
    rule before (0.5) let it pass."""
    from r2s.metrics.observation_check import FlagTolerances, check_observation

    box = slab(40, 69, 30, 59, top_z=0.2)
    masks = mask_of(40, 69, 30, 59, 1)
    depth = np.where(masks > 0, 0.8, 1.0)
    shift = np.eye(4)
    shift[0, 3] = 6 * 0.8 / F
    tol = (FlagTolerances(max_free_space=10.0) if min_iou_kept == 0.75 else
           FlagTolerances(max_free_space=10.0, min_iou_kept=min_iou_kept))
    assert FlagTolerances().min_iou_kept == 0.75
    check = check_observation([box.copy().apply_transform(shift)], [1], K, CAMERA, depth,
                              masks, world_from_object={1: shift},
                              init_world_from_object={1: np.eye(4)},
                              centres_in_object={1: box.centroid}, tolerances=tol)
    block = check.blocks[1]
    assert block["iou"] == pytest.approx(720 / 1080, abs=1e-4)
    assert block["iou_seen"] == pytest.approx(1.0, abs=1e-9)
    assert block["flagged"] is flagged
    if flagged:
        assert "fell from 1.00 where it was seen to 0.67 (< 75% of it)" in block["reason"]


def test_ucd_split_at_the_tables_level_separates_what_the_mask_took_in():
    """A 40 mm box on the table (z = 0) is seen on its top face (exact points) and its mask
    also takes in 25 table points 0.2 m behind it, at z = 0.001: UCD over all points is
    the mean with those 0.2 m, the split leaves them out (UCD ~ 0) and says their share."""
    from r2s.metrics.observation import _ucd_above_support

    box = trimesh.creation.box(extents=[0.04, 0.04, 0.04]).apply_translation([0.0, 0.0, 0.02])
    rng = np.random.default_rng(1)
    top = np.c_[rng.uniform(-0.02, 0.02, 75), rng.uniform(-0.02, 0.02, 75), np.full(75, 0.04)]
    table = np.c_[np.full(25, 0.22), rng.uniform(-0.02, 0.02, 25), np.full(25, 0.001)]
    pts = np.r_[top, table]
    plane = (np.zeros(3), np.array([0.0, 0.0, 2.0]))  # the normal need not be unit
    above_mm, share = _ucd_above_support(pts, box, plane)
    assert share == pytest.approx(0.25)
    assert above_mm < 1e-3
    all_mm = 1000.0 * unilateral_chamfer_m(pts, box)
    assert all_mm == pytest.approx(0.25 * 200.0, abs=0.5)  # each table point 0.2 m off the x = 0.02 face
    assert _ucd_above_support(pts, box, None) == (None, None)
    assert _ucd_above_support(table, box, plane) == (None, 1.0)
