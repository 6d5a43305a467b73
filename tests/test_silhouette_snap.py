"""The outline snap (r2s/geometry/silhouette_snap.py) against a box of known size seen
from an oblique camera: a shape 2 mm too wide all round comes back to the box's outline,
heights untouched; where the outline meets another instance, or where the camera saw past
the new surface, nothing moves."""

import numpy as np
import pytest
import trimesh
from scipy import ndimage

from r2s.geometry.camera import intrinsics, look_at
from r2s.geometry.raycast import raycast_view
from r2s.geometry.silhouette_snap import mask_signed_distance_px, snap_outline

W, H = 320, 240
K = intrinsics(W, H, 45.0)
UP = np.array([0.0, 0.0, 1.0])
EXTENTS = np.array([0.10, 0.06, 0.08])


def _box(extents) -> trimesh.Trimesh:
    """A box standing on z = 0, subdivided so its edges carry vertices every few mm."""
    box = trimesh.creation.box(extents=extents)
    box.apply_translation([0.0, 0.0, extents[2] / 2])
    for _ in range(4):
        box = box.subdivide()
    return box


def _camera() -> np.ndarray:
    """40 deg above the table, 0.45 m away."""
    elev = np.radians(40.0)
    eye = 0.45 * np.array([0.3 * np.cos(elev), -np.cos(elev), np.sin(elev)])
    return look_at(eye, np.array([0.0, 0.0, 0.04]))


def _render(mesh: trimesh.Trimesh, wfc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mesh's silhouette and the depth image of the mesh on a table (z <= 0)."""
    table = trimesh.creation.box(extents=[1.0, 1.0, 0.01])
    table.apply_translation([0.0, 0.0, -0.005])
    depth, index, _ = raycast_view([mesh, table], K, wfc, W, H)
    return index == 0, depth.astype(np.float64)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


def _grown(extents, grow_m: float) -> trimesh.Trimesh:
    """The box grown horizontally by ``grow_m`` on every side (same height)."""
    e = np.array(extents, dtype=float)
    e[:2] += 2 * grow_m
    return _box(e)


def test_signed_distance_is_zero_halfway_between_pixel_centres():
    mask = np.zeros((9, 9), bool)
    mask[2:7, 2:7] = True
    phi = mask_signed_distance_px(mask)
    assert phi[4, 6] == pytest.approx(-0.5)  # last pixel in
    assert phi[4, 7] == pytest.approx(0.5)   # first pixel out
    assert phi[4, 4] == pytest.approx(-2.5)


def test_a_box_two_mm_too_wide_comes_back_to_its_outline():
    wfc = _camera()
    truth = _box(EXTENTS)
    mask, depth = _render(truth, wfc)
    labels = mask.astype(np.int64)
    wide = _grown(EXTENTS, 0.002)
    before = _iou(_render(wide, wfc)[0], mask)
    snapped, report = snap_outline(wide, mask, labels, depth, K, wfc, UP)
    after = _iou(_render(snapped, wfc)[0], mask)
    assert before < 0.95
    assert after > 0.97, (before, after)
    assert report.vertices_moved > 0
    # moves are horizontal: every vertex keeps its height
    np.testing.assert_allclose(snapped.vertices[:, 2], wide.vertices[:, 2], atol=1e-12)
    # the outline's edges come back to the truth: the bottom edge facing the camera and
    # the right-hand one, within 0.5 mm in the median and 1.5 mm everywhere (the shifts
    # are read off a mask of whole pixels, 1.5 mm at this distance); the hidden far sides
    # of a box seen from above do not make its outline and stay where they were
    before_v, after_v = wide.vertices, snapped.vertices
    on_base = np.abs(before_v[:, 2]) < 1e-9
    near = on_base & np.isclose(before_v[:, 1], -EXTENTS[1] / 2 - 0.002)
    right = on_base & np.isclose(before_v[:, 0], EXTENTS[0] / 2 + 0.002)
    for edge, axis, true in ((near, 1, -EXTENTS[1] / 2), (right, 0, EXTENTS[0] / 2)):
        inner = edge & (np.abs(before_v[:, 1 - axis]) < EXTENTS[1 - axis] / 2 - 0.005)
        assert np.median(after_v[inner, axis]) == pytest.approx(true, abs=5e-4)
        assert np.abs(after_v[inner, axis] - true).max() < 1.5e-3


def _too_narrow():
    """The camera, the true box's mask, depth and labels, and the box 2 mm too narrow."""
    wfc = _camera()
    mask, depth = _render(_box(EXTENTS), wfc)
    return wfc, mask, depth, mask.astype(np.int64), _grown(EXTENTS, -0.002)


def test_a_box_two_mm_too_narrow_grows_where_the_camera_read_nothing():
    wfc, mask, _, labels, narrow = _too_narrow()
    no_depth = np.full((H, W), np.nan)
    snapped, _ = snap_outline(narrow, mask, labels, no_depth, K, wfc, UP)
    before = _iou(_render(narrow, wfc)[0], mask)
    after = _iou(_render(snapped, wfc)[0], mask)
    assert before < 0.95
    assert after > 0.97, (before, after)


def test_no_growth_where_the_camera_saw_past_the_new_surface():
    wfc, mask, depth, labels, narrow = _too_narrow()
    # the mask's outer 3 px and everything around it read a wall 1.5 m away (mask bleed
    # onto a background seen far behind the object)
    seen_past = depth.copy()
    seen_past[~ndimage.binary_erosion(mask, iterations=3)] = 1.5
    snapped, report = snap_outline(narrow, mask, labels, seen_past, K, wfc, UP)
    assert report.refused_seen_past > 0
    grown = np.abs(snapped.vertices - narrow.vertices).max()
    assert grown < 2e-4, grown


def test_an_outline_against_another_instance_is_left_alone():
    wfc = _camera()
    truth = _box(EXTENTS)
    mask, depth = _render(truth, wfc)
    wide = _grown(EXTENTS, 0.002)
    # every pixel around the mask belongs to another instance (an occluder or a neighbour)
    labels = np.full(mask.shape, 7, dtype=np.int64)
    labels[mask] = 1
    snapped, report = snap_outline(wide, mask, labels, depth, K, wfc, UP)
    assert report.refused_other > 0
    assert report.vertices_moved == 0
    np.testing.assert_array_equal(snapped.vertices, wide.vertices)


def test_no_move_into_another_object():
    """A box 2 mm too narrow whose mask (the true box's) would grow it onto a neighbour
    standing right against its true side: given the neighbour, the grown side stops short
    of it (no vertex beside it inside it or within 0.5 mm of it; above its 50 mm top the
    side grows on), the other sides still grow."""
    wfc, mask, _, labels, narrow = _too_narrow()
    neighbour = trimesh.creation.box(extents=[0.04, 0.10, 0.05])
    neighbour.apply_translation([EXTENTS[0] / 2 + 0.02, 0.0, 0.025])  # touches x = +50 mm
    no_depth = np.full((H, W), np.nan)
    free, _ = snap_outline(narrow, mask, labels, no_depth, K, wfc, UP)
    kept, report = snap_outline(narrow, mask, labels, no_depth, K, wfc, UP, others=[neighbour])
    right = (narrow.vertices[:, 0] > EXTENTS[0] / 2 - 0.003) & (narrow.vertices[:, 2] < 0.045)
    assert free.vertices[right, 0].max() > EXTENTS[0] / 2 - 2e-4  # without: it reaches it
    assert report.refused_overlap > 0
    assert kept.vertices[right, 0].max() < EXTENTS[0] / 2 - 4e-4
    front = narrow.vertices[:, 1] < -EXTENTS[1] / 2 + 0.003
    assert kept.vertices[front, 1].min() < narrow.vertices[front, 1].min() - 1e-3


def test_the_base_resting_on_another_object_stays_where_it_rests():
    """A bar lying across a narrower block, completed 2 mm too wide all round: its outline
    comes in (also along the overhanging ends of its base), but the base vertices that rest
    on the block (the block within 3 mm below them) do not move, so what carries the bar is
    unchanged. The block's pixels count as background here, so nothing else stops them."""
    wfc = _camera()
    block = trimesh.creation.box(extents=[0.06, 0.06, 0.05])
    block.apply_translation([0.0, 0.0, 0.025])
    bar_extents = np.array([0.16, 0.03, 0.02])
    bar = _box(bar_extents)
    bar.apply_translation([0.0, 0.0, 0.05])
    table = trimesh.creation.box(extents=[1.0, 1.0, 0.01])
    table.apply_translation([0.0, 0.0, -0.005])
    _, index, _ = raycast_view([bar, block, table], K, wfc, W, H)
    mask = index == 0
    labels = mask.astype(np.int64)
    wide = _grown(bar_extents, 0.002)
    wide.apply_translation([0.0, 0.0, 0.05])
    no_depth = np.full((H, W), np.nan)
    v = wide.vertices
    on_block = (v[:, 2] < 0.0505) & (np.abs(v[:, 0]) < 0.029)
    overhang = (v[:, 2] < 0.0505) & (np.abs(v[:, 0]) > 0.04)
    free, _ = snap_outline(wide, mask, labels, no_depth, K, wfc, UP)
    kept, report = snap_outline(wide, mask, labels, no_depth, K, wfc, UP, others=[block])
    moved_free = np.linalg.norm(free.vertices - v, axis=1)
    moved_kept = np.linalg.norm(kept.vertices - v, axis=1)
    assert moved_free[on_block].max() > 5e-4  # without the block the base comes in too
    assert report.pinned >= on_block.sum()
    np.testing.assert_array_equal(kept.vertices[on_block], v[on_block])
    assert moved_kept[overhang].max() > 5e-4  # the overhanging base still comes in
    top = v[:, 2] > 0.069
    assert moved_kept[top].max() > 5e-4
