"""physopt's cut of overlapping collision pieces (r2s/physopt/piece_overlap.py), against
boxes whose overlap and cut are known exactly."""

import numpy as np
import pytest
import trimesh

from r2s.physopt.piece_overlap import (BELOW_SUPPORT_M, CUT_CLEARANCE_M, piece_overlaps,
                                       shave_overlaps)


def _box(size_m, centre_m=(0.0, 0.0, 0.0)):
    return trimesh.creation.box(extents=size_m,
                                transform=trimesh.transformations.translation_matrix(centre_m))


def _pose(translation_m):
    pose = np.eye(4)
    pose[:3, 3] = translation_m
    return pose


def _plate_and_cube():
    """A: a 10 x 10 x 4 cm piece on the table whose visual mesh is 5 mm lower (the piece
    overshoots its mesh, as a convex piece spanning a plate's dish does); B: a 4 cm cube
    resting on A's visual mesh, so 5 mm inside A's piece."""
    pieces = {1: [_box([0.10, 0.10, 0.04])], 2: [_box([0.04, 0.04, 0.04])]}
    meshes = {1: _box([0.10, 0.10, 0.035], [0.0, 0.0, -0.0025]), 2: _box([0.04, 0.04, 0.04])}
    poses = {1: _pose([0.0, 0.0, 0.02]), 2: _pose([0.01, 0.0, 0.035 + 0.02])}
    return pieces, meshes, poses


def test_later_piece_cut_at_the_earlier_ones_top():
    pieces, meshes, poses = _plate_and_cube()
    overlaps = piece_overlaps(pieces, poses)
    assert len(overlaps) == 1
    # Bullet adds its margins (about 1 mm per hull) to the 5 mm the pieces share
    assert overlaps[0].depth_m == pytest.approx(0.005 + 2e-3, abs=2e-4)

    out, report = shave_overlaps(pieces, meshes, poses, order=[1, 2])
    assert out[1][0] is pieces[1][0]                      # the earlier object is never cut
    lowest = out[2][0].vertices[:, 2].min() + poses[2][2, 3]
    assert lowest == pytest.approx(0.04 + CUT_CLEARANCE_M, abs=1e-6)
    # the cut removes exactly the slab below that level: 4 x 4 cm x (5 + 1) mm
    removed = pieces[2][0].volume - out[2][0].volume
    assert removed == pytest.approx(0.04 * 0.04 * (0.005 + CUT_CLEARANCE_M), rel=1e-6)
    assert report[2].depth_before_m > 4e-3 and report[2].depth_after_m == 0.0
    assert not piece_overlaps(out, poses)                 # nothing for depenetration to push


def test_order_decides_which_piece_is_cut():
    pieces, meshes, poses = _plate_and_cube()
    out, report = shave_overlaps(pieces, meshes, poses, order=[2, 1])
    assert out[2][0] is pieces[2][0] and set(report) == {1}
    # A is cut from B's bottom (z = 0.035) down by the clearance
    assert out[1][0].vertices[:, 2].max() + poses[1][2, 3] == pytest.approx(
        0.035 - CUT_CLEARANCE_M, abs=1e-6)


def test_a_visual_overlap_geomopt_keeps_is_cut_not_pushed():
    # B's visual mesh reaches 2 mm into A's (an overlap geomopt accepts: <= 3 mm), its
    # piece 7 mm into A's piece: the cut ends B's piece at A's piece, so depenetration
    # does not push B up by the pieces' 7 mm for the meshes' 2 mm
    pieces, meshes, poses = _plate_and_cube()
    poses[2] = _pose([0.01, 0.0, 0.033 + 0.02])
    out, report = shave_overlaps(pieces, meshes, poses, order=[1, 2])
    lowest = out[2][0].vertices[:, 2].min() + poses[2][2, 3]
    assert lowest == pytest.approx(0.04 + CUT_CLEARANCE_M, abs=1e-6)
    assert report[2].depth_before_m > 6e-3 and not piece_overlaps(out, poses)


def test_visual_meshes_that_interpenetrate_are_left_to_depenetration():
    # the visual meshes are the pieces: B is really sunk 8 mm into A (and A 3 mm into
    # the table), which the depenetration must lift, not a cut hide
    pieces = {1: [_box([0.10, 0.10, 0.04])], 2: [_box([0.04, 0.04, 0.04])]}
    meshes = {1: pieces[1][0], 2: pieces[2][0]}
    poses = {1: _pose([0.0, 0.0, 0.02 - 0.003]), 2: _pose([0.0, 0.0, 0.04 + 0.02 - 0.011])}
    support = (np.zeros(3), np.array([0.0, 0.0, 1.0]))
    out, report = shave_overlaps(pieces, meshes, poses, order=[1, 2], support=support)
    assert out[1][0] is pieces[1][0] and out[2][0] is pieces[2][0] and report == {}


def test_a_visual_overlap_of_3_5_mm_is_cut_not_pushed():
    # B's visual mesh 3.5 mm into A's (the tenth fresh set's scene_01 pair that geomopt
    # read at 2 mm on its grid and kept): cut at A's top, B stays where it was seen
    pieces = {1: [_box([0.10, 0.10, 0.04])], 2: [_box([0.04, 0.04, 0.04])]}
    meshes = {1: pieces[1][0], 2: pieces[2][0]}
    poses = {1: _pose([0.0, 0.0, 0.02]), 2: _pose([0.0, 0.0, 0.04 + 0.02 - 0.0035])}
    support = (np.zeros(3), np.array([0.0, 0.0, 1.0]))
    out, report = shave_overlaps(pieces, meshes, poses, order=[1, 2], support=support)
    lowest = out[2][0].vertices[:, 2].min() + poses[2][2, 3]
    assert lowest == pytest.approx(0.04 + CUT_CLEARANCE_M, abs=1e-6)
    assert out[1][0] is pieces[1][0] and not piece_overlaps(out, poses)


def test_piece_below_the_table_cut_at_the_table_and_others_untouched():
    # piece 1 overshoots its visual mesh by 3 mm below the table; piece 2 by less than
    # the allowance
    pieces = {1: [_box([0.05, 0.05, 0.05])], 2: [_box([0.05, 0.05, 0.05])]}
    meshes = {1: _box([0.05, 0.05, 0.047], [0.0, 0.0, 0.0015]), 2: _box([0.05, 0.05, 0.05])}
    poses = {1: _pose([0.0, 0.0, 0.025 - 0.003]),
             2: _pose([0.2, 0.0, 0.025 - 0.5 * BELOW_SUPPORT_M])}
    support = (np.zeros(3), np.array([0.0, 0.0, 1.0]))
    out, _ = shave_overlaps(pieces, meshes, poses, order=[1, 2], support=support)
    assert out[1][0].vertices[:, 2].min() + poses[1][2, 3] == pytest.approx(0.0, abs=1e-9)
    assert out[1][0].volume == pytest.approx(0.05 * 0.05 * 0.047, rel=1e-6)
    assert out[2][0] is pieces[2][0]


def test_apart_pieces_are_returned_as_given():
    pieces = {1: [_box([0.05, 0.05, 0.05])], 2: [_box([0.05, 0.05, 0.05])]}
    poses = {1: _pose([0.0, 0.0, 0.025]), 2: _pose([0.0505, 0.0, 0.025])}  # 0.5 mm apart
    out, report = shave_overlaps(pieces, {1: pieces[1][0], 2: pieces[2][0]}, poses,
                                 order=[1, 2])
    assert out[1][0] is pieces[1][0] and out[2][0] is pieces[2][0] and report == {}


def test_a_piece_standing_on_the_table_is_not_cut_from_below():
    # A: a thin slab piece (8 mm) on the table whose visual mesh ends 1 mm before B (the
    # piece overshoots it by 2 cm sideways); B: a 4 cm cube standing on the table with 2 cm
    # of its base over the piece's edge: the shortest way out is up (8 mm, Bullet ~10 mm),
    # but B stands on the table, so cutting its base would drop it: left to depenetration
    pieces = {1: [_box([0.10, 0.10, 0.008])], 2: [_box([0.04, 0.04, 0.04])]}
    meshes = {1: _box([0.079, 0.10, 0.008], [-0.0105, 0.0, 0.0]), 2: pieces[2][0]}
    poses = {1: _pose([0.0, 0.0, 0.004]), 2: _pose([0.05 + 0.0, 0.0, 0.02])}
    support = (np.zeros(3), np.array([0.0, 0.0, 1.0]))
    overlaps = piece_overlaps(pieces, poses)
    assert overlaps and abs(overlaps[0].normal_world[2]) > 0.9
    out, report = shave_overlaps(pieces, meshes, poses, order=[1, 2], support=support)
    assert out[2][0] is pieces[2][0] and report == {}
    # the same cube 3 mm above the table (resting on the slab only) is cut
    poses[2] = _pose([0.05, 0.0, 0.023])
    out, report = shave_overlaps(pieces, meshes, poses, order=[1, 2], support=support)
    assert out[2][0] is not pieces[2][0] and set(report) == {2}


def test_a_shallow_geometric_overlap_is_found_with_bullets_margins():
    # two 5 cm cubes side by side, 1 mm into each other along x only: Bullet inflates each
    # hull by its 1 mm margin, so it reads 1 + 2 = 3 mm, over the 1.5 mm tolerance, though
    # the boxes overlap by less than that along x
    pieces = {1: [_box([0.05, 0.05, 0.05])], 2: [_box([0.05, 0.05, 0.05])]}
    poses = {1: _pose([0.0, 0.0, 0.025]), 2: _pose([0.049, 0.0, 0.025])}
    overlaps = piece_overlaps(pieces, poses)
    assert len(overlaps) == 1
    assert overlaps[0].depth_m == pytest.approx(0.001 + 2e-3, abs=2e-4)
    out, report = shave_overlaps(pieces, {1: pieces[1][0], 2: pieces[2][0]}, poses,
                                 order=[1, 2])
    # the later cube is cut 1 mm past the earlier one's face, and reads no overlap after
    assert out[2][0].vertices[:, 0].min() + poses[2][0, 3] == pytest.approx(
        0.025 + CUT_CLEARANCE_M, abs=1e-6)
    assert set(report) == {2} and not piece_overlaps(out, poses)
