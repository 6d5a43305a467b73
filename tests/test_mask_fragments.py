"""Mask ids that are pieces of one object (r2s/geometry/mask_fragments.py), on hand-made
images whose answer is known: a box split in two by a line, a sliver along an occluder,
two touching objects that are not one (different depth; same depth, different colour;
a mask that bleeds onto its neighbour), and an id with a prior."""

from __future__ import annotations

import numpy as np

import pytest

from r2s.geometry.mask_fragments import (MAX_COLOUR_DISTANCE, MAX_COLOUR_SET_DISTANCE,
                                         SLIVER_MIN_CONTINUOUS_FRACTION, boundary_evidence,
                                         fragment_parents, merge_masks)

H, W = 80, 120


def _plane_depth(z0: float = 0.8, slope_per_px: float = 0.0005) -> np.ndarray:
    rows = np.arange(H, dtype=np.float64)[:, None]
    return np.broadcast_to(z0 + slope_per_px * rows, (H, W)).copy()


def _image(colour_left, colour_right, split_col: int) -> np.ndarray:
    rgb = np.full((H, W, 3), 128, np.uint8)
    rgb[20:60, 20:split_col] = colour_left
    rgb[20:60, split_col:100] = colour_right
    return rgb


def test_a_split_box_is_one_object():
    """One box face (a sloped, continuous depth; one colour) cut by a vertical line into
    ids 1 and 7: 7 (the smaller) goes to 1; the merged mask is the box's."""
    masks = np.zeros((H, W), np.int32)
    masks[20:60, 20:70] = 1
    masks[20:60, 70:100] = 7
    depth = _plane_depth()
    rgb = _image((200, 40, 40), (200, 40, 40), 70)
    parents = fragment_parents(masks, depth, rgb)
    assert list(parents) == [7] and parents[7][0] == 1
    merged = merge_masks(masks, parents)
    assert set(np.unique(merged)) == {0, 1} and (merged == 1).sum() == 40 * 80


def test_ids_the_user_labelled_differently_are_never_merged():
    """The split box above, its two ids declared in objects.json as a "duck" and a "cup"
    (a duck against a cup of its colour, at a far camera): two objects, kept apart. The
    same labels, or a label on one id only, leave the join to the image."""
    masks = np.zeros((H, W), np.int32)
    masks[20:60, 20:70] = 1
    masks[20:60, 70:100] = 7
    depth = _plane_depth()
    rgb = _image((200, 40, 40), (200, 40, 40), 70)
    assert fragment_parents(masks, depth, rgb, declared_ids=[1, 7],
                            labels={1: "cup", 7: "duck"}) == {}
    for labels in ({1: "cup", 7: "cup"}, {1: "cup"}):
        parents = fragment_parents(masks, depth, rgb, declared_ids=list(labels),
                                   labels=labels)
        assert list(parents) == [7] and parents[7][0] == 1


def test_objects_at_different_depths_are_not_merged():
    """Same colour, but the right one stands 40 mm in front: a depth jump along the
    whole boundary."""
    masks = np.zeros((H, W), np.int32)
    masks[20:60, 20:70], masks[20:60, 70:100] = 1, 2
    depth = _plane_depth()
    depth[:, 70:] -= 0.04
    assert fragment_parents(masks, depth, _image((90, 90, 200), (90, 90, 200), 70)) == {}


def test_touching_objects_of_different_colour_are_not_merged_even_with_bleed():
    """Two boxes side by side at the same depth (continuous across the boundary) but of
    different colours; id 2's mask bleeds 3 px onto id 1 (so its first pixels carry id 1's
    colour): not merged."""
    masks = np.zeros((H, W), np.int32)
    masks[20:60, 20:67], masks[20:60, 67:100] = 1, 2  # 2 bled 3 px past the edge at 70
    rgb = _image((200, 40, 40), (40, 160, 60), 70)
    assert fragment_parents(masks, _plane_depth(), rgb) == {}
    ev = boundary_evidence(masks, _plane_depth(), rgb)[0]
    assert ev.continuous_fraction == 1.0 and ev.colour_distance > 100


def test_a_sliver_goes_to_its_object_and_a_prior_is_never_a_fragment():
    """A 2-px strip of an object given id 9: it goes to the object. With a prior on 9
    (a prior is a whole object) the larger id goes to 9 instead; with priors on both,
    nothing is merged."""
    masks = np.zeros((H, W), np.int32)
    masks[20:60, 20:98], masks[20:60, 98:100] = 4, 9
    rgb = _image((30, 30, 30), (30, 30, 30), 98)
    depth = _plane_depth()
    assert fragment_parents(masks, depth, rgb)[9][0] == 4
    assert fragment_parents(masks, depth, rgb, protected_ids=[9])[4][0] == 9
    assert fragment_parents(masks, depth, rgb, protected_ids=[4, 9]) == {}


def test_corrected_input_relabels_a_fragment_and_drops_its_object():
    """Through the hook every stage uses: the split piece's pixels carry the object's id,
    its ObjectSpec is gone, one warning line names the merge, merged_ids records it."""
    from r2s.io.input_scene import Camera, InputScene, ObjectSpec
    from r2s.scene_model import corrected_input

    masks = np.zeros((H, W), np.int32)
    masks[20:60, 20:70], masks[20:60, 70:100] = 1, 7
    cam = Camera(K=np.array([[100.0, 0, 60], [0, 100.0, 40], [0, 0, 1]]),
                 world_from_camera=np.eye(4), width=W, height=H)
    scene = InputScene(rgb=_image((200, 40, 40), (200, 40, 40), 70),
                       depth_m=_plane_depth().astype(np.float32), masks=masks, camera=cam,
                       objects=[ObjectSpec(1, "box"), ObjectSpec(7, "object_7")])
    out = corrected_input(scene, {})
    assert out.ids == [1] and out.merged_ids == {7: 1}
    assert (out.masks == 1).sum() == 40 * 80 and not (out.masks == 7).any()
    # (the identity pose also gets the line of a table tilted beyond any real one)
    merges = [w for w in out.warnings if "is taken as part of" in w]
    assert len(merges) == 1 and "instance 7 is taken as part of instance 1" in merges[0]
    assert corrected_input(scene, {}, merge_fragments=False).ids == [1, 7]


def test_a_declared_id_is_kept_over_a_larger_undeclared_piece():
    """A split where the segmenter's new id (7) got the larger piece: the merge keeps the
    id the user declared (1, with its objects.json entry) and 7 becomes the fragment;
    undeclared on both sides, the larger piece's id is kept, as before."""
    masks = np.zeros((H, W), np.int32)
    masks[20:60, 20:45], masks[20:60, 45:100] = 1, 7
    rgb = _image((200, 40, 40), (200, 40, 40), 45)
    depth = _plane_depth()
    parents = fragment_parents(masks, depth, rgb, declared_ids=[1])
    assert list(parents) == [7] and parents[7][0] == 1
    assert list(fragment_parents(masks, depth, rgb)) == [1]
    assert list(fragment_parents(masks, depth, rgb, declared_ids=[1, 7])) == [1]


def test_a_thin_split_with_depth_missing_along_the_cut_is_one_object():
    """A marker 10 px thick cut across into ids 3 and 6: 10 boundary pairs, depth read on
    only 5 of them (dark, thin: holes). Joined when at least 4 pairs carry depth (the rule
    before asked for 8), and not when no reading lies within 3 px of the cut (nothing to
    tell a split from two objects touching)."""
    masks = np.zeros((H, W), np.int32)
    masks[35:45, 20:80], masks[35:45, 80:100] = 3, 6
    rgb = _image((30, 30, 30), (30, 30, 30), 70)
    depth = _plane_depth()
    depth[35:45, 79:81] = np.nan
    depth[35:40, 79:81] = 0.8 + 0.0005 * np.arange(35, 40)[:, None]  # 5 rows read
    ev = boundary_evidence(masks, depth, rgb)[0]
    assert (ev.pairs, ev.boundary_pairs) == (5, 10)
    parents = fragment_parents(masks, depth, rgb)
    assert parents and parents[6][0] == 3
    depth[35:45, 76:84] = np.nan             # no reading within 3 px of the cut
    assert boundary_evidence(masks, depth, rgb)[0].pairs == 0
    assert fragment_parents(masks, depth, rgb) == {}


def test_a_split_read_only_a_few_pixels_from_the_cut_is_judged_on_those_readings():
    """The same marker, with no reading on either side of the cut (2 px each way) but one
    3 px or less away: each boundary pixel takes its side's nearest reading, 10 pairs, the
    plane's depth on both sides, joined. With the right piece 3 cm behind the left one
    (two objects, one in front of the other), the filled pairs show the jump and the ids
    stay apart."""
    masks = np.zeros((H, W), np.int32)
    masks[35:45, 20:80], masks[35:45, 80:100] = 3, 6
    rgb = _image((30, 30, 30), (30, 30, 30), 70)
    depth = _plane_depth()
    depth[35:45, 78:82] = np.nan
    ev = boundary_evidence(masks, depth, rgb)[0]
    assert (ev.pairs, ev.boundary_pairs, ev.continuous_fraction) == (10, 10, 1.0)
    assert fragment_parents(masks, depth, rgb)[6][0] == 3
    depth[:, 80:] += 0.03
    ev = boundary_evidence(masks, depth, rgb)[0]
    assert (ev.pairs, ev.continuous_fraction) == (10, 0.0)
    assert fragment_parents(masks, depth, rgb) == {}


def _checker(colour_a, colour_b, cell_px: int = 6) -> np.ndarray:
    """(H, W, 3) uint8 checkerboard of two colours (a printed, textured surface)."""
    rows, cols = np.indices((H, W))
    board = ((rows // cell_px + cols // cell_px) % 2).astype(bool)
    rgb = np.empty((H, W, 3), np.uint8)
    rgb[~board], rgb[board] = colour_a, colour_b
    return rgb


def test_a_split_textured_object_is_one_object():
    """A striped black-and-white face (a printed box) cut where its left piece is 70 %
    white and its right piece 70 % black: the mean colours differ by
    sqrt(3) * 0.4 * 230 ~ 159, far more than ``MAX_COLOUR_DISTANCE``, but both strips hold
    exactly the same two colours (nearest-colour distance 0), so the pieces are one
    object."""
    masks = np.zeros((H, W), np.int32)
    masks[20:60, 20:70], masks[20:60, 70:100] = 1, 5
    white, black = (250, 250, 250), (20, 20, 20)
    rows = np.arange(H) % 10
    rgb = np.empty((H, W, 3), np.uint8)
    rgb[:, :70] = np.where((rows < 7)[:, None, None], white, black)[:, :1]
    rgb[:, 70:] = np.where((rows < 3)[:, None, None], white, black)[:, :1]
    ev = boundary_evidence(masks, _plane_depth(), rgb)[0]
    assert ev.colour_distance == pytest.approx(np.sqrt(3) * 0.4 * 230, abs=3.0)
    assert ev.colour_set_distance == pytest.approx(0.0, abs=1e-9)
    assert fragment_parents(masks, _plane_depth(), rgb)[5][0] == 1


def test_touching_textured_objects_of_different_colours_are_not_merged():
    """Two checkered boxes side by side at the same depth, red/white and blue/green: the
    nearest colours across the boundary are 80 or more apart (white to green is
    sqrt(250^2 + 70^2 + 250^2) ~ 360, red to blue ~ 320 ...), so they stay two objects."""
    masks = np.zeros((H, W), np.int32)
    masks[20:60, 20:70], masks[20:60, 70:100] = 1, 2
    left = _checker((220, 30, 30), (250, 250, 250))
    right = _checker((30, 30, 220), (30, 180, 30))
    rgb = np.where((np.arange(W) < 70)[None, :, None], left, right).astype(np.uint8)
    ev = boundary_evidence(masks, _plane_depth(), rgb)[0]
    assert ev.continuous_fraction == 1.0 and ev.colour_set_distance > 3 * MAX_COLOUR_SET_DISTANCE
    assert fragment_parents(masks, _plane_depth(), rgb) == {}


def test_a_checkered_ball_beside_a_grey_box_of_its_mean_colour_is_not_merged():
    """Left a grey box (135, 135, 135), right a black-and-white checker (20 / 250) whose
    mean is within a few units of that grey: the means agree, but no colour of the
    checker is near the grey (median nearest distance sqrt(3) * 115 ~ 199), so they are
    two objects."""
    masks = np.zeros((H, W), np.int32)
    masks[20:60, 20:70], masks[20:60, 70:100] = 1, 2
    rgb = _checker((250, 250, 250), (20, 20, 20))
    rgb[:, :70] = 135
    ev = boundary_evidence(masks, _plane_depth(), rgb)[0]
    assert ev.continuous_fraction == 1.0 and ev.colour_distance < MAX_COLOUR_DISTANCE
    assert ev.colour_set_distance == pytest.approx(np.sqrt(3) * 115, abs=1.0)
    assert fragment_parents(masks, _plane_depth(), rgb) == {}


def _sliver_scene():
    """A red box (id 4), a 3 x 30 px strip of it (id 9) along a blue occluder (id 5, 40 mm
    nearer), the strip in the edge's mixed colours (see the test below)."""
    masks = np.zeros((H, W), np.int32)
    masks[20:60, 20:70] = 4
    masks[30:60, 70:73] = 9
    masks[20:60, 73:100] = 5  # the occluder, 40 mm nearer
    depth = _plane_depth()
    depth[:, 73:] -= 0.04
    rgb = np.full((H, W, 3), 128, np.uint8)
    rgb[20:60, 20:70] = (200, 40, 40)
    rgb[20:60, 73:100] = (40, 40, 200)
    rgb[30:60, 70:73] = (180, 60, 60)       # 35 off the box: the edge's mix
    rgb[30:40, 70:73] = (40, 40, 200)       # and a little of the occluder's blue
    return masks, depth, rgb


def test_a_sliver_on_a_noisy_boundary_joins_down_to_90_percent_continuous():
    """The strip's 30 boundary pairs with the box, a few of its rows reading 20 mm off
    (a far camera's noise: over the 8 mm jump at 0.8 m). 2 rows off: 93 % continuous, a
    sliver, joined; 4 rows off: 87 %, under SLIVER_MIN_CONTINUOUS_FRACTION, apart (the
    strip's colours pass only the sliver rule)."""
    assert SLIVER_MIN_CONTINUOUS_FRACTION == 0.90
    for rows_off, joined in ((2, True), (4, False)):
        masks, depth, rgb = _sliver_scene()
        depth[30:30 + rows_off, 70:73] += 0.02
        ev = [e for e in boundary_evidence(masks, depth, rgb)
              if {e.small_id, e.large_id} == {4, 9}][0]
        assert ev.continuous_fraction == pytest.approx(1 - rows_off / 30)
        assert ev.is_sliver() is joined
        assert (fragment_parents(masks, depth, rgb) == {9: (4, ev.describe())}) is joined


def test_a_sliver_of_edge_colours_joins_but_not_one_of_another_colour():
    """A 3 x 30 px strip (id 9) of a red box (id 4) along a nearer object's edge reads the
    edge's mixed colours, 30 RGB units off the box's (above the ordinary 8-unit match,
    means 30 apart: the means rule's 40 would take it as well, so the strip's mean is
    pushed away by a few pixels of the occluder's blue): a sliver, joined. The same strip
    in green (set distance > 40) is not."""
    masks, depth, rgb = _sliver_scene()
    ev = [e for e in boundary_evidence(masks, depth, rgb) if {e.small_id, e.large_id} == {4, 9}]
    assert len(ev) == 1 and ev[0].is_sliver()
    assert ev[0].colour_set_distance > MAX_COLOUR_SET_DISTANCE
    assert ev[0].colour_distance > MAX_COLOUR_DISTANCE
    parents = fragment_parents(masks, depth, rgb)
    assert list(parents) == [9] and parents[9][0] == 4
    rgb[30:60, 70:73] = (40, 200, 40)
    assert fragment_parents(masks, depth, rgb) == {}


def test_the_halves_of_a_split_with_a_sliver_along_the_cut_are_one_object():
    """The segmenter cut one box face in two (ids 1 and 7) and gave the 4 px strip along
    the cut an id of its own (9): the two halves share no boundary, each shares one with
    the strip. The strip joins one half; then, on the masks with it merged, that half
    shares the strip's 40 px boundary with the other half, which joins too."""
    masks = np.zeros((H, W), np.int32)
    masks[20:60, 20:68], masks[20:60, 68:72], masks[20:60, 72:100] = 1, 9, 7
    depth = _plane_depth()
    rgb = _image((200, 40, 40), (200, 40, 40), 70)
    parents = fragment_parents(masks, depth, rgb)
    assert {i: p for i, (p, _) in parents.items()} == {9: 1, 7: 1}
    assert set(np.unique(merge_masks(masks, parents))) == {0, 1}
