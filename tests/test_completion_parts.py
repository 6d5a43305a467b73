"""A completed object seen in two parts of its mask (cut apart by an occluder) gets the
union of the parts' own footprints (r2s/geometry/completion.py ``part_hulls``)
where something else is seen standing between them, on hand-made point sets with known
footprints."""

import numpy as np
import trimesh
from scipy.spatial import ConvexHull

from r2s.geometry.completion import complete_from_points, footprint_sdf, part_hulls


def _grid(x0, x1, y0, y1, z, step=0.002):
    xs, ys = np.meshgrid(np.arange(x0, x1 + 1e-9, step), np.arange(y0, y1 + 1e-9, step))
    return np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)])


def test_the_footprint_of_two_parts_is_the_union_of_their_hulls():
    a = _grid(0.0, 0.04, 0.0, 0.02, 0.0)[:, :2]             # 40 x 20 mm
    b = _grid(0.10, 0.12, 0.06, 0.10, 0.0)[:, :2]           # 20 x 40 mm, off to the side
    speck = np.array([[0.125, 0.105]])                      # 1 point: joins part b
    xy = np.vstack([a, b, speck])
    parts = np.r_[np.zeros(len(a)), np.ones(len(b)), [7]].astype(int)
    hull = ConvexHull(xy)
    query = np.array([[0.02, 0.01],      # inside a
                      [0.11, 0.08],      # inside b
                      [0.07, 0.04],      # between them: inside the joint hull only
                      [0.12, 0.10],      # corner of b, the speck's side
                      [0.20, 0.20]])     # outside everything
    by_part = footprint_sdf(part_hulls(xy, parts), query)
    whole = footprint_sdf(hull.equations, query)
    np.testing.assert_allclose(by_part[:2], [-0.01, -0.01], atol=1e-9)  # 10 mm inside
    assert by_part[2] > 0.01 and whole[2] < 0                # the gap: out, 10+ mm away
    assert by_part[3] < 0                                    # the speck widened b's hull
    assert by_part[4] > 0 and whole[4] > 0
    # one part only, or parts of fewer than MIN_PART_POINTS points: the whole hull
    assert part_hulls(xy, np.zeros(len(xy), int)) is None
    assert part_hulls(xy, np.r_[np.zeros(len(xy) - 5), np.ones(5)].astype(int)) is None


def test_the_space_between_two_parts_is_left_empty_where_something_stands_in_it():
    # the two visible ends of an L-shaped bracket 20 mm high whose corner is hidden: the
    # tops of a 40 x 20 mm end and a 20 x 40 mm end. Between them, in the triangle that
    # one hull across both would fill, something else is seen: a small object standing on
    # the table (its points 5-12 mm up, under the bracket's 20 mm top: the space is its)
    # or one lying on top (its points 30 mm up: the bracket may go on under it).
    a = _grid(0.0, 0.04, 0.0, 0.02, 0.02)
    b = _grid(0.10, 0.12, 0.06, 0.10, 0.02)
    pts = np.vstack([a, b])
    parts = np.r_[np.zeros(len(a)), np.ones(len(b))].astype(int)
    plane = (np.zeros(3), np.array([0.0, 0.0, 1.0]))
    standing = _grid(0.065, 0.075, 0.035, 0.045, 0.0)
    standing[:, 2] = np.linspace(0.005, 0.012, len(standing))
    lying_on = _grid(0.065, 0.075, 0.035, 0.045, 0.03)

    def complete(others):
        return complete_from_points(pts, *plane, point_parts=parts, outlier_factor=0,
                                    below_points_world=[others])

    def inside(shape, p):
        m = shape.mesh.copy().apply_transform(shape.world_from_object)
        return trimesh.proximity.ProximityQuery(m).signed_distance(np.atleast_2d(p)) > 0

    by_part, whole = complete(standing), complete(lying_on)
    between = [0.06, 0.03, 0.01]         # in the hull, outside both ends, beside the object
    assert inside(whole, between)[0] and not inside(by_part, between)[0]
    ends = [[0.02, 0.01, 0.01], [0.11, 0.08, 0.01]]
    assert inside(by_part, ends).all() and inside(whole, ends).all()
    # the two ends' volume, 2 x (40 x 20 x 20) mm^3, within 10 % (3 mm cells, marching
    # cubes rounds the edges; measured 5 % short); the joint hull's is over 3 times that
    ends_m3 = 2 * 0.04 * 0.02 * 0.02
    assert abs(by_part.mesh.volume - ends_m3) < 0.10 * ends_m3
    assert whole.mesh.volume > 3 * ends_m3
    # without parts: one hull across, standing on what is seen under it (the old way)
    one = complete_from_points(pts, *plane, outlier_factor=0, below_points_world=[standing])
    assert inside(one, [0.06, 0.03, 0.016])[0] and one.bottom_m > 0.01
