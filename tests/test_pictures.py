"""The annotated pictures: which objects rollout.png names as moved and by how much, the
ids init.png writes and where, and render.png's colour bar."""

from __future__ import annotations

import numpy as np
import pytest

from r2s.geometry.overlay import fit_overlay, label_anchors
from r2s.metrics.motion import moved_objects, object_motions
from r2s.metrics.rendering import ERROR_FULL_SCALE, error_colour_bar
from r2s.pictures.annotate import heat_colour
from r2s.pictures.rollout_picture import (MOVED_RGB, Frame, motion_labels, moved_summary,
                                          rollout_picture)
from r2s.sim.rollout import Trajectory


def _rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _trajectory() -> Trajectory:
    """Three objects over 3 samples.

    5 (mug): COM moves (30, 40, 0) mm = 50 mm and turns 10 deg about z (COM at the origin);
    6 (box): moves 3 mm and turns 1 deg (below both limits: not moved);
    7 (can): stays put but turns 3 deg about z (moved by rotation); its COM is 2 cm off
    the origin on x, so its COM travels 2 * 0.02 * sin(1.5 deg) m.
    """
    ids = np.array([5, 6, 7])
    poses = np.tile(np.eye(4), (3, 3, 1, 1))
    poses[:, 1, :3, 3] = [0.2, 0, 0]
    poses[:, 2, :3, 3] = [-0.2, 0, 0]
    poses[1, 0, :3, 3] = [0.015, 0.02, 0]
    poses[2, 0, :3, 3] = [0.03, 0.04, 0]
    poses[2, 0, :3, :3] = _rot_z(10.0)
    poses[2, 1, :3, 3] = [0.203, 0, 0]
    poses[2, 1, :3, :3] = _rot_z(1.0)
    poses[2, 2, :3, :3] = _rot_z(3.0)
    com = np.array([[0, 0, 0], [0, 0, 0], [0.02, 0, 0]], dtype=float)
    zeros = np.zeros((3, 3, 3))
    return Trajectory(ids=ids, times_s=np.array([0.0, 0.5, 1.0]), world_from_object=poses,
                      linear_velocity_mps=zeros, angular_velocity_radps=zeros,
                      com_in_object=com)


LABELS = {5: "mug", 6: "box", 7: "can"}


def test_object_motions_against_a_known_rollout() -> None:
    motions = object_motions(_trajectory(), LABELS)
    by_id = {m.id: m for m in motions}
    assert by_id[5].displacement_mm == pytest.approx(50.0, abs=1e-9)
    assert by_id[5].rotation_deg == pytest.approx(10.0, abs=1e-6)
    assert by_id[6].displacement_mm == pytest.approx(3.0, abs=1e-9)
    assert by_id[6].rotation_deg == pytest.approx(1.0, abs=1e-6)
    chord_mm = 1000 * 2 * 0.02 * np.sin(np.radians(1.5))
    assert by_id[7].displacement_mm == pytest.approx(chord_mm, abs=1e-9)
    assert by_id[7].rotation_deg == pytest.approx(3.0, abs=1e-6)
    assert [m.id for m in moved_objects(motions)] == [5, 7]        # largest first
    np.testing.assert_allclose(by_id[5].com_end_m, [0.03, 0.04, 0.0], atol=1e-12)
    assert by_id[5].caption == "5 mug: 50.0 mm, 10.0 deg"


def test_motion_labels_name_the_moved_and_unstable_objects() -> None:
    motions = object_motions(_trajectory(), LABELS)
    labels = motion_labels(motions, unstable_ids=[5])
    assert [(lab.id, lab.text, lab.highlighted) for lab in labels] == [
        (5, "5 mug: 50.0 mm, 10.0 deg, unstable", True),
        (6, "6", False),
        (7, f"7 can: {motions[2].displacement_mm:.1f} mm, 3.0 deg", True),
    ]
    assert moved_summary(motions, [5]).startswith("moved (red): 5 mug: 50.0 mm")
    still = object_motions(_trajectory(), LABELS, moved_translation_m=1.0,
                           moved_rotation_deg=90.0)
    assert moved_summary(still).startswith("no object moved")


def test_rollout_picture_outlines_only_the_moved_object() -> None:
    """Top-down camera; object 5 slides from the left square to the right one, 6 stays."""
    h, w = 80, 120
    K = np.array([[100.0, 0, (w - 1) / 2], [0, 100.0, (h - 1) / 2], [0, 0, 1]])
    world_from_camera = np.eye(4)
    world_from_camera[:3, :3] = np.diag([1.0, -1.0, -1.0])     # looking down -z
    world_from_camera[2, 3] = 1.0
    first_ids = np.full((h, w), -1)
    last_ids = np.full((h, w), -1)
    first_ids[30:50, 10:30] = 5
    last_ids[30:50, 70:90] = 5
    first_ids[60:75, 40:55] = last_ids[60:75, 40:55] = 6
    rgb = np.full((h, w, 3), 200, np.uint8)
    first = Frame(np.where(first_ids[..., None] >= 0, 50, rgb).astype(np.uint8), first_ids)
    last = Frame(np.where(last_ids[..., None] >= 0, 50, rgb).astype(np.uint8), last_ids)
    poses = np.tile(np.eye(4), (2, 2, 1, 1))
    poses[1, 0, :3, 3] = [0.6, 0, 0]                           # 5 moves 0.6 m along x
    traj = Trajectory(ids=np.array([5, 6]), times_s=np.array([0.0, 1.0]),
                      world_from_object=poses, linear_velocity_mps=np.zeros((2, 2, 3)),
                      angular_velocity_radps=np.zeros((2, 2, 3)), com_in_object=np.zeros((2, 3)))
    motions = object_motions(traj, {5: "mug", 6: "box"})
    assert [m.id for m in motions if m.moved] == [5]
    pic = rollout_picture(first, last, motions, K, world_from_camera, 1.0, "caption")
    assert pic.shape[1] == 2 * w + 4 and pic.shape[0] > h
    right = pic[:h, w + 4:]
    red = np.all(right == MOVED_RGB, axis=-1)
    # the red outline runs along the border of 5's last silhouette (bottom edge, clear of
    # the label drawn above it), and nowhere in the left panel
    assert red[49, 72:88].all()
    assert not np.all(pic[:h, :w] == MOVED_RGB, axis=-1).any()
    # the object that stayed is faded towards grey; 5 keeps its colour inside
    assert right[68, 47].min() > 100 and (right[45, 80] == 50).all()


def test_init_labels_sit_at_the_mask_centroids() -> None:
    masks = np.zeros((60, 80), np.int32)
    masks[10:20, 10:30] = 3                                    # centroid (19.5, 14.5)
    masks[30:50, 40:60] = 8                                    # a C shape: centroid outside
    masks[35:45, 45:60] = 0
    anchors = label_anchors(masks, [3, 8, 9])
    assert set(anchors) == {3, 8}                              # 9 is not in the masks
    assert anchors[3] == pytest.approx((19.5, 14.5))
    x, y = anchors[8]
    assert masks[int(y), int(x)] == 8
    rows, cols = np.nonzero(masks == 8)
    d = np.hypot(cols - cols.mean(), rows - rows.mean())
    assert np.hypot(x - cols.mean(), y - rows.mean()) == pytest.approx(d.min())
    rgb = np.full((60, 80, 3), 120, np.uint8)
    rendered = np.where(masks == 3, 0, np.where(masks == 8, 1, -1))
    plain = fit_overlay(rgb, rendered, masks, [3, 8])
    named = fit_overlay(rgb, rendered, masks, [3, 8], labels={3: "mug", 8: "can"})
    changed = np.any(named != plain, axis=-1)
    assert changed[14, 19] and changed[int(y), int(x)]         # a dot at each anchor
    assert not changed[55:, :].any()                           # nothing far from them


def test_render_colour_bar_spans_the_error_scale() -> None:
    width = 1920                                               # render.png's width at 640 px
    bar = error_colour_bar(width)
    assert bar.shape[1] == width and bar.dtype == np.uint8
    row = bar[12].astype(int)
    # the ramp: the run of heat colours (blue = 0) that ends at the bar's right frame
    end = width - 21
    start = end
    while start > 0 and row[start - 1, 2] == 0:
        start -= 1
    ramp = row[start:end]
    assert len(ramp) > width // 2
    brightness = ramp[:, 0] + ramp[:, 1]
    assert (np.diff(brightness) >= 0).all()                    # error grows left to right
    np.testing.assert_array_equal(heat_colour(np.array([0.0, 1.0])), [[0, 0, 0], [255, 255, 0]])
    assert ramp[1].max() <= 3                                  # error 0: black
    assert tuple(ramp[-1]) == pytest.approx((255, 255, 0), abs=3)  # ERROR_FULL_SCALE: yellow
    # the middle of the ramp has the colour of half the full scale
    mid = ramp[len(ramp) // 2]
    assert tuple(mid) == pytest.approx(tuple(heat_colour(np.array(0.5))), abs=3)
    assert ERROR_FULL_SCALE == 128.0
