"""A small mask id seen past an occluder from a larger one (r2s/geometry/occluded_fragments.py),
on hand-made images whose answer is known: a long box (id 1, 0.80 m away) hidden in its
middle by a nearer one (id 3, 0.70 m), its far end seen as id 9; and the cases that must
stay apart: the gap is table, the "occluder" is farther than both pieces, the piece's
colour is not the box's, the pieces are too far apart in 3-D, the piece has a prior."""

from __future__ import annotations

import numpy as np

from r2s.geometry.mask_fragments import fragment_parents
from r2s.geometry.occluded_fragments import MAX_GAP_M, bridge, occluded_parents

H, W = 120, 160
K = np.array([[400.0, 0.0, 80.0], [0.0, 400.0, 60.0], [0.0, 0.0, 1.0]])
BOX = (200, 40, 40)


def _scene(occluder_z: float = 0.70, piece_colour=BOX, gap_label: int = 3,
           piece_z: float = 0.80, occluder_px: int = 20):
    """Box id 1 at columns 20-69, occluder (or table, ``gap_label`` 0) at 70-89
    (``occluder_px`` columns), the box's far end id 9 in the 10 columns after it, all in
    rows 40-79; table elsewhere at 0.9 m."""
    masks = np.zeros((H, W), np.int32)
    depth = np.full((H, W), 0.9)
    rgb = np.full((H, W, 3), 128, np.uint8)
    masks[40:80, 20:70], depth[40:80, 20:70], rgb[40:80, 20:70] = 1, 0.80, BOX
    gap = slice(70, 70 + occluder_px)
    masks[30:90, gap], depth[30:90, gap] = gap_label, occluder_z
    rgb[30:90, gap] = (40, 60, 200) if gap_label else 128
    if gap_label == 0:
        depth[30:90, gap] = 0.9
    end = slice(70 + occluder_px, 80 + occluder_px)
    masks[40:80, end], depth[40:80, end], rgb[40:80, end] = 9, piece_z, piece_colour
    return masks, depth, rgb


def test_the_far_end_of_a_hidden_box_joins_it():
    """Gap 21 px = 42 mm at 0.8 m, the occluder 100 mm in front: joined, past id 3."""
    masks, depth, rgb = _scene()
    b = bridge(masks, depth, rgb, K, 9, 1)
    assert b is not None and b.occluder_ids == (3,)
    assert abs(b.gap_px - 21.0) < 0.5
    assert abs(b.gap_m - 21.0 * 0.8 / 400.0) < 1e-3
    assert b.hidden_fraction == 1.0 and b.colour_distance < 1.0
    parents = fragment_parents(masks, depth, rgb, K=K)
    assert list(parents) == [9] and parents[9][0] == 1 and "past instance 3" in parents[9][1]
    # without the camera, only the boundary test runs: the pieces share no boundary
    assert fragment_parents(masks, depth, rgb) == {}


def test_pieces_with_table_between_stay_apart():
    masks, depth, rgb = _scene(gap_label=0)
    assert bridge(masks, depth, rgb, K, 9, 1) is None
    assert occluded_parents(masks, depth, rgb, K) == {}


def test_an_occluder_behind_the_pieces_hides_nothing():
    """The object between stands 50 mm behind both pieces: the camera sees the space
    between them, so no object runs through it."""
    masks, depth, rgb = _scene(occluder_z=0.85)
    assert bridge(masks, depth, rgb, K, 9, 1) is None


def test_a_piece_of_another_colour_stays_apart():
    masks, depth, rgb = _scene(piece_colour=(40, 200, 40))
    assert bridge(masks, depth, rgb, K, 9, 1) is None


def test_pieces_too_far_apart_in_depth_stay_apart():
    """The piece lies 150 mm behind the box end (the occluder still in front of both):
    farther than MAX_GAP_M."""
    masks, depth, rgb = _scene(piece_z=0.95, occluder_z=0.70)
    assert MAX_GAP_M < 0.15
    assert bridge(masks, depth, rgb, K, 9, 1) is None


def test_a_piece_with_a_prior_is_a_whole_object():
    masks, depth, rgb = _scene()
    assert occluded_parents(masks, depth, rgb, K, protected_ids=[9]) == {}
    assert fragment_parents(masks, depth, rgb, protected_ids=[9], K=K) == {}


def test_a_declared_piece_keeps_its_id():
    """The user named id 9 (an objects.json entry), not the segmenter's larger id 1: the
    object is reconstructed under 9."""
    masks, depth, rgb = _scene()
    parents = fragment_parents(masks, depth, rgb, declared_ids=[9], K=K)
    assert list(parents) == [1] and parents[1][0] == 9


def test_a_piece_past_an_occluder_two_pixels_wide_joins_it():
    """A far camera: the occluder between the box and its end is 2 px wide (the path 3 px,
    too short to leave readings past its ends), 100 mm in front of both: joined on its
    two pixels' readings. The same thin gap over the table, or a thin object behind the
    pieces, keeps them apart."""
    masks, depth, rgb = _scene(occluder_px=2)
    b = bridge(masks, depth, rgb, K, 9, 1)
    assert b is not None and b.occluder_ids == (3,)
    assert abs(b.gap_px - 3.0) < 0.5 and b.hidden_fraction == 1.0
    assert occluded_parents(masks, depth, rgb, K) == {9: (1, b.describe())}
    masks, depth, rgb = _scene(occluder_px=2, gap_label=0)
    assert bridge(masks, depth, rgb, K, 9, 1) is None
    masks, depth, rgb = _scene(occluder_px=2, occluder_z=0.85)
    assert bridge(masks, depth, rgb, K, 9, 1) is None


def test_a_one_pixel_occluder_is_not_enough():
    """One occluder pixel on the path (the gap 2 px): fewer readings than
    MIN_SHORT_PATH_READINGS, so the pieces stay apart."""
    masks, depth, rgb = _scene(occluder_px=1)
    assert bridge(masks, depth, rgb, K, 9, 1) is None


def test_a_piece_labelled_as_another_object_is_not_joined():
    """The box's far end (id 9) declared with a label of its own: another object, apart;
    with the box's label it is still joined."""
    masks, depth, rgb = _scene()
    other = fragment_parents(masks, depth, rgb, declared_ids=[1, 9], K=K,
                             labels={1: "box", 9: "ball"})
    assert other == {}
    same = fragment_parents(masks, depth, rgb, declared_ids=[1, 9], K=K,
                            labels={1: "box", 9: "box"})
    assert list(same) == [9] and same[9][0] == 1
