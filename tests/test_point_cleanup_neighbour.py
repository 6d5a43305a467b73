"""Bleed onto a nearer neighbour (r2s/geometry/point_cleanup.py, the neighbour test), on a
hand-made mask whose answer is known.

A small object seen past a nearer one: its own surface reads 0.85 m in two pieces (150 and
80 px) that a row of holes cuts apart, and its mask took in a 70 px strip of the
neighbour in front (0.71 m), 4 px wide along the neighbour's mask. The strip is 47 % of
the object's largest piece, so the size test alone (25 %) keeps it."""

from __future__ import annotations

import numpy as np

from r2s.geometry.point_cleanup import object_point_mask


def _scene(strip_rows: slice, neighbour_depth_m: float):
    """(points, pixels, depths, neighbour pixels, neighbour depths, strip selector)."""
    own = [(r, c, 0.85) for r in range(10, 20) for c in range(10, 25)]        # 150 px
    own += [(r, c, 0.85) for r in range(22, 30) for c in range(10, 20)]       # 80 px, past a gap
    strip = [(r, c, 0.71) for r in range(strip_rows.start, strip_rows.stop) for c in range(30, 34)]
    rows = np.array(own + strip, dtype=np.float64)
    pixels = rows[:, :2].astype(np.int64)
    depth = rows[:, 2]
    points = np.c_[pixels[:, 1] * 1e-3, pixels[:, 0] * 1e-3, np.full(len(rows), 0.1)]
    neighbour = np.array([(r, c) for r in range(0, 60) for c in range(34, 50)], dtype=np.int64)
    is_strip = np.zeros(len(rows), dtype=bool)
    is_strip[len(own):] = True
    return points, pixels, depth, neighbour, np.full(len(neighbour), neighbour_depth_m), is_strip


def test_a_strip_of_the_nearer_neighbour_is_dropped_whatever_its_size():
    pts, pix, z, nb, nb_z, strip = _scene(slice(10, 27), 0.71)
    plane = (np.zeros(3), np.array([0.0, 0.0, 1.0]))
    without = object_point_mask(pts, pix, z, *plane, neighbour_pixels=nb)
    assert without[strip].all()  # 68 px against 150: the size test keeps it
    keep = object_point_mask(pts, pix, z, *plane, neighbour_pixels=nb, neighbour_depth_m=nb_z)
    assert not keep[strip].any() and keep[~strip].all()


def test_a_strip_at_another_depth_than_the_neighbour_is_kept():
    """The same strip beside a neighbour that reads 0.60 m there: it is not that
    neighbour's surface, and the test leaves it to the size rule (kept)."""
    pts, pix, z, nb, nb_z, strip = _scene(slice(10, 27), 0.60)
    plane = (np.zeros(3), np.array([0.0, 0.0, 1.0]))
    keep = object_point_mask(pts, pix, z, *plane, neighbour_pixels=nb, neighbour_depth_m=nb_z)
    assert keep.all()


def test_the_objects_own_largest_piece_is_never_dropped():
    """A neighbour at the object's own depth along its largest piece (two boxes side by
    side): the largest piece stays, as do the others not all within the band."""
    pts, pix, z, _, _, strip = _scene(slice(10, 27), 0.71)
    nb = np.array([(r, c) for r in range(0, 60) for c in range(25, 29)], dtype=np.int64)
    plane = (np.zeros(3), np.array([0.0, 0.0, 1.0]))
    keep = object_point_mask(pts, pix, z, *plane, neighbour_pixels=nb,
                             neighbour_depth_m=np.full(len(nb), 0.85))
    assert keep[~strip].all()
