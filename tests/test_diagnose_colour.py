"""The colour test of diagnose (r2s/diagnose/stats/colour_test.py) on hand-made residual
maps with a known answer: three registered priors textured in 12 x 12 px blocks of random
grey, their depth residual a known function of the grey level plus 1 mm of noise."""

from __future__ import annotations

import numpy as np
import pytest

from r2s.diagnose.data import DepthMapData, Residuals
from r2s.diagnose.stats.colour_test import test_surface_colour as colour_test

H, W = 120, 160
BOXES = {1: (10, 50, 10, 70), 2: (60, 110, 10, 70), 3: (20, 100, 90, 150)}
"""id -> (row0, row1, col0, col1) of each object's pixels."""


def _scene(residual_of_grey, seed: int = 0, prior_ids=(1, 2, 3), by_row: float = 0.0):
    rng = np.random.default_rng(seed)
    blocks = rng.uniform(0.1, 0.95, size=(H // 12 + 1, W // 12 + 1))
    grey = np.kron(blocks, np.ones((12, 12)))[:H, :W]
    ids = np.zeros((H, W), dtype=np.int64)
    for oid, (r0, r1, c0, c1) in BOXES.items():
        ids[r0:r1, c0:c1] = oid
    rows = np.arange(H)[:, None] * np.ones((1, W))
    residual = residual_of_grey(grey) + by_row * (rows / H) + rng.normal(0, 0.001, (H, W))
    residual[ids == 0] = np.nan
    dm = DepthMapData(residual_m=residual, depth_m=np.full((H, W), 0.6), on_object=ids > 0,
                      object_id=ids, grey=grey, prior_ids=tuple(prior_ids))
    return Residuals(depth_map=dm)


def test_dark_surfaces_read_farther_is_found_and_sized():
    """8 mm x (1 - grey): the slope is -8 mm per unit grey in every object; found (|z| far
    above the threshold of 6) with the median slope within 1.5 mm of -8."""
    found = colour_test(_scene(lambda g: 0.008 * (1.0 - g)))
    assert found is not None and found.structured
    assert found.z < -10
    assert found.slope_mm == pytest.approx(-8.0, abs=1.5)
    assert set(found.slopes_mm) == {1, 2, 3}
    assert "darker surfaces read farther" in found.pattern


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noise_alone_and_a_geometric_error_are_not_colour(seed: int):
    """Noise alone, and a residual that grows 6 mm down the image (geometry, not texture):
    |z| < 4, nothing reported."""
    for by_row in (0.0, 0.006):
        found = colour_test(_scene(lambda g: 0.0 * g, seed=seed, by_row=by_row))
        assert found is not None and not found.structured, (by_row, found.z)
        assert abs(found.z) < 4.0


def test_completions_say_nothing():
    """No registered prior (completions are built from the same depth): no test."""
    assert colour_test(_scene(lambda g: 0.008 * (1.0 - g), prior_ids=())) is None
    assert colour_test(Residuals()) is None
