"""The free-space test against a hand-made view: seen past, occluded, inside the mask."""

from __future__ import annotations

import numpy as np

from r2s.geometry.camera import backproject
from r2s.geometry.free_space import free_space_violations, view_constraint

# camera 1 m above the table looking straight down; 1 px = 1 cm at the table
K = np.array([[100.0, 0, 49.5], [0, 100.0, 49.5], [0, 0, 1]])
CAM = np.array([[1.0, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 1.0], [0, 0, 0, 1]])


def _view():
    depth = np.full((100, 100), 1.0)          # the table
    mask = np.zeros((100, 100), bool)
    mask[40:60, 40:60] = True                 # the object: a 20 cm square, 10 cm tall
    depth[mask] = 0.9
    depth[40:60, 70:90] = 0.5                 # an occluder to the right, 50 cm tall
    return depth, mask


def test_seen_past_occluded_and_inside():
    depth, mask = _view()
    view = view_constraint(K, CAM, depth, mask)
    # model points 10 cm above the table (camera depth 0.9), normals up (facing the camera)
    px = np.array([[50, 50], [50, 30], [50, 75], [50, 60], [50, 62]])   # (row, col)
    d = np.zeros((100, 100))
    d[px[:, 0], px[:, 1]] = 0.9
    pts, pix = backproject(np.where(d > 0, d, np.nan), K, CAM, return_pixels=True)
    order = [int(np.flatnonzero((pix == p).all(axis=1))[0]) for p in px]
    pts = pts[order]
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    viol, targets, tested = free_space_violations(view, pts, normals, 0.01)
    assert tested == 5
    # inside the mask: fine; left over the table: seen past; right under the occluder:
    # hidden, fine; one pixel off the mask edge: within the 1.5 px margin; three: seen past
    assert viol.tolist() == [False, True, False, False, True]
    # pulled to the nearest mask pixel at the same camera depth (0.9 m)
    x_cam = np.array([(40 - 49.5) * 0.009, (50 - 49.5) * 0.009, 0.9])  # column 40
    np.testing.assert_allclose(targets[0], [x_cam[0], -x_cam[1], 0.1], atol=1e-9)
    x_cam = np.array([(59 - 49.5) * 0.009, (50 - 49.5) * 0.009, 0.9])  # column 59
    np.testing.assert_allclose(targets[1], [x_cam[0], -x_cam[1], 0.1], atol=1e-9)


def test_points_facing_away_or_outside_the_image_are_not_tested():
    depth, mask = _view()
    view = view_constraint(K, CAM, depth, mask)
    pts = np.array([[-0.2, 0.0, 0.1], [3.0, 0.0, 0.1]])
    viol, _, tested = free_space_violations(view, pts, np.array([[0, 0, -1.0], [0, 0, 1.0]]))
    assert tested == 0 and not viol.any()


def test_no_reading_on_another_instance_says_nothing():
    """An occluder that reads no depth (dark, glossy) hides what is behind it: a model point
    under its mask is not seen past when the other masks are given; a point over the table
    where the reading is lost still is."""
    depth, mask = _view()
    depth[40:60, 70:90] = np.nan                 # the occluder reads no depth
    depth[20:25, 40:60] = np.nan                 # a hole in the table's reading
    others = np.zeros_like(mask)
    others[40:60, 70:90] = True
    px = np.array([[50, 75], [22, 50]])          # under the occluder; over the table's hole
    d = np.zeros((100, 100))
    d[px[:, 0], px[:, 1]] = 0.9
    pts, pix = backproject(np.where(d > 0, d, np.nan), K, CAM, return_pixels=True)
    pts = pts[[int(np.flatnonzero((pix == p).all(axis=1))[0]) for p in px]]
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    masks_unknown, _, _ = free_space_violations(view_constraint(K, CAM, depth, mask), pts,
                                                normals, 0.01)
    assert masks_unknown.tolist() == [True, True]
    given, _, tested = free_space_violations(
        view_constraint(K, CAM, depth, mask, other_masks=others), pts, normals, 0.01)
    assert tested == 2 and given.tolist() == [False, True]
