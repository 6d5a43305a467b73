"""The hidden back of an object seen only as a face (r2s/geometry/hidden_back.py)."""

from __future__ import annotations

import numpy as np
import pytest

from r2s.geometry.completion import complete_from_points
from r2s.geometry.hidden_back import MIN_DEEPER_M, hidden_back

EYE = np.array([0.0, -0.6, 0.35])  # 30 deg above the table, looking along +y
PLANE = (np.zeros(3), np.array([0.0, 0.0, 1.0]))


def _face(width_m: float, height_m: float, y_m: float = 0.0, step_m: float = 0.002,
          noise_m: float = 0.0005, seed: int = 0) -> np.ndarray:
    """(N, 3) points on a vertical face at y = ``y_m``, across x in +-width/2, z up to
    ``height_m``, with Gaussian noise along y."""
    x, z = np.meshgrid(np.arange(-width_m / 2, width_m / 2 + 1e-9, step_m),
                       np.arange(0.008, height_m + 1e-9, step_m), indexing="ij")
    rng = np.random.default_rng(seed)
    y = y_m + rng.normal(0.0, noise_m, x.size)
    return np.c_[x.ravel(), y, z.ravel()]


def test_a_face_gets_a_back_as_deep_as_it_is_wide_at_its_top():
    # a 60 mm wide, 70 mm tall face whose top something nearer hides: the back's points lie
    # at the face's top height and run from the face 60 mm away from the camera
    pts = _face(0.06, 0.07, y_m=0.10)
    back = hidden_back(pts, *PLANE, EYE, cell_m=0.002)
    assert back is not None
    assert np.all(np.abs(back[:, 2] - 0.07) < 0.002)
    assert back[:, 1].min() == pytest.approx(0.10, abs=0.002)  # from the face's median
    assert back[:, 1].max() == pytest.approx(0.10 + 0.06, abs=0.004)
    assert back[:, 0].min() == pytest.approx(-0.03, abs=0.003)
    assert back[:, 0].max() == pytest.approx(0.03, abs=0.003)


def test_completed_with_its_back_the_face_becomes_a_box_as_deep_as_wide():
    pts = _face(0.06, 0.07, y_m=0.10)
    slab = complete_from_points(pts, *PLANE, cell_m=0.002)
    box = complete_from_points(np.concatenate([pts, hidden_back(pts, *PLANE, EYE)]), *PLANE,
                               cell_m=0.002)
    slab_depth = np.ptp(slab.mesh.vertices[:, 1])
    box_extent = np.ptp(box.mesh.vertices, axis=0)
    assert slab_depth < 0.015
    assert box_extent[1] == pytest.approx(0.06, rel=0.1)  # as deep as the face is wide
    assert box_extent[0] == pytest.approx(0.06, rel=0.1)
    assert box_extent[2] == pytest.approx(0.07, rel=0.05)


def test_no_back_where_the_top_is_seen_or_the_object_is_low_or_as_deep_as_wide():
    # the top seen: points span 50 mm along the view, over 0.6 of the 70 mm height
    x, y = np.meshgrid(np.arange(-0.03, 0.03, 0.002), np.arange(0.10, 0.15, 0.002))
    top = np.c_[x.ravel(), y.ravel(), np.full(x.size, 0.07)]
    assert hidden_back(np.concatenate([_face(0.06, 0.07, y_m=0.10), top]), *PLANE, EYE) is None
    assert hidden_back(_face(0.06, 0.018), *PLANE, EYE) is None  # under 20 mm: no topple
    # a face no wider than it was seen thick: nothing to add
    narrow = _face(0.006, 0.07, noise_m=0.003, seed=1)
    assert hidden_back(narrow, *PLANE, EYE) is None
    assert MIN_DEEPER_M == pytest.approx(0.01)


def test_the_back_runs_away_from_the_camera_whichever_side_it_is_on():
    # the same face seen from the other side (camera at +y): the back runs towards -y
    pts = _face(0.06, 0.07, y_m=0.10)
    back = hidden_back(pts, *PLANE, np.array([0.0, 0.8, 0.35]), cell_m=0.002)
    assert back[:, 1].max() == pytest.approx(0.10, abs=0.002)
    assert back[:, 1].min() == pytest.approx(0.10 - 0.06, abs=0.004)
