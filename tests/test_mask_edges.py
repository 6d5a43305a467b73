"""Rim pixels of a mask that bleeds past the object: found exactly on a hand-made image."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from r2s.geometry.mask_edges import foreign_rim_pixels


def _scene():
    """A 40x40 px block 0.50 m from the camera on a background 0.80 m away; the block's
    lowest 6 rows stand on the table (height 0), the rest is 1-5 cm above it."""
    depth = np.full((100, 100), 0.80)
    block = np.zeros((100, 100), dtype=bool)
    block[30:70, 30:70] = True
    depth[block] = 0.50
    height = np.full((100, 100), np.nan)
    height[block] = 0.05
    height[64:70, 30:70] = 0.02   # the block's lower band, above the 4 mm plane band
    return depth, block, height


def test_exact_mask_loses_nothing():
    depth, block, height = _scene()
    assert not foreign_rim_pixels(depth, block, height).any()


def test_bled_rim_is_found_and_only_it():
    depth, block, height = _scene()
    bled = ndimage.binary_dilation(block, iterations=2)
    ring = bled & ~block
    # the ring's lower side is table just in front of the base (no depth jump)
    depth[70:72, 28:72] = 0.505
    height[ring] = np.nan
    height[70:72, 28:72] = 0.001
    foreign = foreign_rim_pixels(depth, bled, height)
    assert foreign[ring].all()          # every bled pixel: far side of the jump or on the table
    assert not foreign[block].any()     # no pixel of the block itself
    # without the plane test the table pixels in front of the base stay
    no_plane = foreign_rim_pixels(depth, bled, None)
    assert not no_plane[70:72, 32:68].any()
    assert no_plane[28:30, 32:68].all()


def test_no_valid_depth_gives_nothing():
    depth = np.full((20, 20), np.nan)
    mask = np.ones((20, 20), dtype=bool)
    assert not foreign_rim_pixels(depth, mask).any()


def test_surface_falling_away_at_a_grazing_angle_is_kept():
    """The side of a round object near its outline is 2 cm farther than the interior
    (more than the jump threshold) but far from the background behind it: kept."""
    depth, block, height = _scene()
    depth[30:70, 30:32] = 0.52
    depth[30:70, 68:70] = 0.52
    assert not foreign_rim_pixels(depth, block, None).any()
    # the same pixels at the background's depth are bleed
    depth[30:70, 30:32] = 0.79
    assert foreign_rim_pixels(depth, block, None)[30:70, 30:32].all()
