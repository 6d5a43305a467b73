"""Rim pixels of a mask that bleeds past the object: found exactly on a hand-made image."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from r2s.geometry.mask_edges import foreign_rim_pixels


def _scene():
    """A 40x40 px block 0.50 m from the camera on a background 0.80 m away."""
    depth = np.full((100, 100), 0.80)
    block = np.zeros((100, 100), dtype=bool)
    block[30:70, 30:70] = True
    depth[block] = 0.50
    return depth, block


def test_exact_mask_loses_nothing():
    depth, block = _scene()
    assert not foreign_rim_pixels(depth, block).any()


def test_bled_rim_is_found_and_only_it():
    depth, block = _scene()
    bled = ndimage.binary_dilation(block, iterations=2)
    ring = bled & ~block
    foreign = foreign_rim_pixels(depth, bled)
    assert foreign[ring].all()          # every bled pixel: far side of the jump
    assert not foreign[block].any()     # no pixel of the block itself
    # bleed onto a surface at the object's own depth (the table at its base) is kept
    depth[70:72, 28:72] = 0.505
    assert not foreign_rim_pixels(depth, bled)[70:72, 32:68].any()


def test_surface_falling_away_at_a_grazing_angle_is_kept():
    """The side of a round object near its outline is 2 cm farther than the interior
    (more than the jump threshold) but far from the background behind it: kept."""
    depth, block = _scene()
    depth[30:70, 30:32] = 0.52
    depth[30:70, 68:70] = 0.52
    assert not foreign_rim_pixels(depth, block).any()
    # the same pixels at the background's depth are bleed
    depth[30:70, 30:32] = 0.79
    assert foreign_rim_pixels(depth, block)[30:70, 30:32].all()


def test_no_valid_depth_gives_nothing():
    depth = np.full((20, 20), np.nan)
    mask = np.ones((20, 20), dtype=bool)
    assert not foreign_rim_pixels(depth, mask).any()
