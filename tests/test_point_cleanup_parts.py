"""point_cleanup's two rules that look at the other masks and at the mask's parts
(r2s/geometry/point_cleanup.py), on hand-made pixel sets with known answers."""

import numpy as np

from r2s.geometry.point_cleanup import interior_pixels, mask_parts, object_point_mask, part_labels


def _square(r0, c0, size):
    rr, cc = np.mgrid[r0:r0 + size, c0:c0 + size]
    return np.column_stack([rr.ravel(), cc.ravel()])


def test_the_ring_runs_only_where_the_mask_borders_no_other_mask():
    own = _square(100, 100, 40)
    alone = interior_pixels(own, 6)
    # more than 6 px (Euclidean) from the outline on all four sides: pixel k of a row or
    # column is k + 1 from the outside, so rows and columns 6..33 of 40, a 28 x 28 core
    assert alone.sum() == 28 * 28
    # another object's mask along the whole left side: no outline there
    left = _square(100, 80, 40)
    left = left[left[:, 1] < 100]
    beside = interior_pixels(own, 6, left)
    # the left ring (columns 0..5, rows 6..33) joins the core
    assert beside.sum() == 28 * (28 + 6)
    assert not beside[own[:, 1] == 139].any()        # the right edge stays ring


def test_mask_parts_close_small_gaps_only():
    a = _square(0, 0, 20)
    b = _square(0, 23, 20)        # a 3-px gap (a depth hole): the same part
    c = _square(0, 60, 10)        # 17 px away: a part of its own
    parts = mask_parts(np.vstack([a, b, c]))
    assert len(set(parts[:400])) == 1 and parts[0] == parts[400]
    assert len(set(parts[800:])) == 1 and parts[800] != parts[0]


def test_a_part_seen_past_an_occluder_is_kept_and_bleed_is_dropped():
    # a flat surface 20 mm above the table at 0.6 m: a large part (40 x 40 px) and, past a
    # 12-px occluder, a small part (12 x 12 px, 9 % of the large one); plus 80 px of bleed
    # on the large part's edge reading 5 cm farther (a surface behind it)
    main, far_part = _square(100, 100, 40), _square(100, 152, 12)
    bleed = _square(140, 100, 40)[:80]
    pixels = np.vstack([main, far_part, bleed])
    depth = np.full(len(pixels), 0.6)
    depth[len(main) + len(far_part):] = 0.65
    points = np.column_stack([pixels * 1e-3, np.full(len(pixels), 0.02)])
    keep = object_point_mask(points, pixels, depth, np.zeros(3), np.array([0.0, 0.0, 1.0]))
    assert keep[:len(main)].all()
    assert keep[len(main):len(main) + len(far_part)].all()     # dropped before this rule
    assert not keep[len(main) + len(far_part):].any()


def test_a_speck_apart_from_the_mask_is_judged_against_the_whole_mask():
    main, speck = _square(100, 100, 40), _square(100, 152, 5)   # 25 px < MIN_PART_PX
    pixels = np.vstack([main, speck])
    depth = np.full(len(pixels), 0.6)
    points = np.column_stack([pixels * 1e-3, np.full(len(pixels), 0.02)])
    keep = object_point_mask(points, pixels, depth, np.zeros(3), np.array([0.0, 0.0, 1.0]))
    assert keep[:len(main)].all() and not keep[len(main):].any()


def test_a_thin_part_with_few_readings_is_sized_by_its_mask_pixels():
    # a screwdriver's shaft past an occluder: a 6 x 40 px strip of the mask (240 px) that
    # reads depth only in 10 patches of 4 x 2 px (80 readings, each patch its own surface
    # region across the holes). Counted by its readings it is a speck (< MIN_PART_PX) and
    # judged against the 40 x 40 px main part's region, so dropped; counted by its mask
    # pixels it is a part of its own, judged against its own regions, so kept.
    main = _square(100, 100, 40)
    strip = _square(100, 160, 40)
    strip = strip[strip[:, 0] < 106]                     # rows 100..105: 240 px
    read = strip[(strip[:, 0] >= 101) & (strip[:, 0] <= 104) & (strip[:, 1] % 4 < 2)]
    assert len(read) == 80
    pixels = np.vstack([main, read])
    depth = np.full(len(pixels), 0.6)
    points = np.column_stack([pixels * 1e-3, np.full(len(pixels), 0.05)])
    plane = (np.zeros(3), np.array([0.0, 0.0, 1.0]))
    by_readings = object_point_mask(points, pixels, depth, *plane)
    assert by_readings[:len(main)].all() and not by_readings[len(main):].any()
    by_mask = object_point_mask(points, pixels, depth, *plane,
                                mask_pixels=np.vstack([main, strip]))
    assert by_mask.all()


def test_part_labels_count_mask_pixels_and_stray_pixels():
    mask = np.vstack([_square(0, 0, 10), _square(0, 30, 4)])    # parts of 100 and 16 px
    readings = np.vstack([_square(0, 0, 10)[::10], _square(0, 30, 4)[:3], [[50, 50]]])
    part, size = part_labels(readings, mask)
    assert list(size[part[[0, 10, 13]]]) == [100, 16, 1]        # the stray pixel: its own
    assert len(set(part[:10])) == 1 and len(set(part)) == 3
    part, size = part_labels(readings, None)                     # its own parts: 10, 3, 1
    assert sorted(size) == [1, 3, 10]
