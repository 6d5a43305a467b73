"""The colour test without priors (r2s/diagnose/stats/texture_depth.py) on hand-made depth
and colour images with a known answer: a printed box face (a tilted plane in 6 x 6 px blocks
of random grey), a shaded cylinder lying across the view (its grey the cosine of the view
angle, a faint print on it) and a printed sphere cap, 0.6-0.7 m away, with 1 mm of depth
noise; with and without each pixel reading 8 mm x (1 - grey) too far."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from r2s.diagnose.stats.texture_depth import Z_THRESHOLD
from r2s.diagnose.stats.texture_depth import test_texture_depth as texture_test

H, W = 160, 200


def _images(seed: int, dark_error_m: float = 0.0, noise_m: float = 0.001,
            noise_blur_px: float = 0.0, print_contrast: float = 1.0):
    """(depth m, grey 0..1, masks) of the three objects; background 0 (no object, no
    depth)."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:H, 0:W].astype(np.float64)
    blocks = rng.uniform(0.1, 0.95, size=(H // 6 + 1, W // 6 + 1))
    printed = np.kron(blocks, np.ones((6, 6)))[:H, :W]
    depth = np.zeros((H, W))
    grey = np.full((H, W), 0.5)
    masks = np.zeros((H, W), dtype=np.int32)
    # 1: a box face, a plane tilted in both directions
    box = (rows >= 10) & (rows < 70) & (cols >= 10) & (cols < 90)
    depth[box] = (0.62 + 0.0004 * rows + 0.0002 * cols)[box]
    grey[box] = (0.5 + print_contrast * (printed - 0.5))[box]
    masks[box] = 1
    # 2: a cylinder of radius 30 px (30 mm) lying along the rows: nearer in the middle,
    # darker where its surface turns away
    cyl = (rows >= 90) & (rows < 150) & (cols >= 20) & (cols < 80)
    x = (cols - 50.0) / 30.0
    cosine = np.sqrt(np.clip(1.0 - x * x, 0.0, 1.0))
    depth[cyl] = (0.65 - 0.03 * cosine)[cyl]
    grey[cyl] = (0.15 + 0.75 * cosine + 0.1 * print_contrast * (printed - 0.5))[cyl]
    masks[cyl] = 2
    # 3: a sphere cap of radius 45 px (45 mm), printed
    r2 = ((rows - 80.0) ** 2 + (cols - 150.0) ** 2) / 45.0 ** 2
    cap = r2 < 0.9
    depth[cap] = (0.70 - 0.045 * np.sqrt(np.clip(1.0 - r2, 0.0, 1.0)))[cap]
    grey[cap] = (0.5 + print_contrast * (printed - 0.5))[cap]
    masks[cap] = 3
    noise = rng.normal(0.0, 1.0, (H, W))
    if noise_blur_px > 0:
        noise = ndimage.gaussian_filter(noise, noise_blur_px)
        noise /= noise.std()
    on = masks > 0
    depth[on] += dark_error_m * (1.0 - grey[on]) + noise_m * noise[on]
    return depth, np.clip(grey, 0.0, 1.0), masks


def test_dark_print_read_farther_is_found_and_sized():
    """8 mm x (1 - grey): reported, z far beyond the threshold, the scene's slope within
    1 mm of -8 mm per unit grey, every object's negative."""
    found = texture_test(*_images(0, dark_error_m=0.008))
    assert found is not None and found.structured and found.source == "texture"
    assert found.z < -2 * Z_THRESHOLD
    assert found.slope_mm == pytest.approx(-8.0, abs=1.0)
    assert set(found.slopes_mm) == {1, 2, 3}
    assert all(s < 0 for s in found.slopes_mm.values())
    assert "darker surfaces read farther" in found.pattern
    assert found.summary()["source"] == "texture"


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_noise_alone_is_not_reported(seed):
    """No colour error, 1 mm of independent noise: |z| < 4 (the threshold is 6)."""
    found = texture_test(*_images(seed))
    assert found is not None
    assert abs(found.z) < 4.0
    assert not found.structured


@pytest.mark.parametrize("seed", [4, 5, 6])
def test_spatially_correlated_noise_is_not_reported(seed):
    """Noise shared by neighbouring pixels (1 mm, blurred over 2 px, as a stereo sensor's):
    the error is clustered on patches, so |z| stays < 4."""
    found = texture_test(*_images(seed, noise_blur_px=2.0))
    assert found is not None
    assert abs(found.z) < 4.0


def test_shading_of_a_curved_surface_is_not_print():
    """The cylinder's shading darkens where its depth grows. Without any print the
    quadratic per patch takes the shading out whole (no grey detail is left: no test).
    With a faint print (a tenth of the contrast) and no colour error, |z| < 4; with the
    8 mm error it is still found."""
    assert texture_test(*_images(7, print_contrast=0.0)) is None
    quiet = texture_test(*_images(7, print_contrast=0.1))
    assert quiet is not None and abs(quiet.z) < 4.0
    loud = texture_test(*_images(7, dark_error_m=0.008, print_contrast=0.1))
    assert loud is not None and loud.structured and loud.z < 0


def test_no_grey_image_or_no_print_gives_no_test():
    depth, grey, masks = _images(8)
    assert texture_test(depth, None, masks) is None
    flat = np.full_like(grey, 0.5)
    assert texture_test(depth, flat, masks) is None


def test_a_depth_step_inside_a_mask_is_left_out():
    """A 2 cm step across the printed box (two faces of one object) with no colour error:
    the patches it crosses are skipped, and nothing is reported."""
    depth, grey, masks = _images(9)
    step = (masks == 1) & (np.arange(W)[None, :] >= 50)
    depth[step] += 0.02
    found = texture_test(depth, grey, masks)
    assert found is not None and abs(found.z) < 4.0
