"""A depth-sensor model: what a consumer RGB-D camera would report for a true depth map.

At noise level 1 (``level`` scales every term; 0 is a perfect sensor):

- axial noise with standard deviation ``1.0 mm + 2.0 mm * (z / 1 m)^2`` (1.5 mm at 0.5 m,
  3 mm at 1 m, the quadratic growth of structured-light and stereo sensors), partly
  spatially correlated;
- no reading next to depth discontinuities (most pixels on the jump, some one pixel
  further) and on grazing surfaces (view ray within ~75-84 deg of the surface normal);
- a few random dropouts (isolated pixels and small blobs).

Systematic errors (``scale``, ``offset_m``) are applied to the true depth first; they are
the ``depth_scale`` and ``depth_offset_m`` injected effects.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

AXIAL_BASE_M = 0.0010
AXIAL_QUADRATIC_M = 0.0020
"""Axial sigma = level * (AXIAL_BASE_M + AXIAL_QUADRATIC_M * z^2), z in metres."""
EDGE_JUMP_FRACTION = 0.02
EDGE_JUMP_MIN_M = 0.005
"""A neighbour differing by more than max(EDGE_JUMP_MIN_M, EDGE_JUMP_FRACTION * z) is a jump."""
EDGE_DROP = 0.8
EDGE_RING_DROP = 0.35
GRAZING_COS_START = 0.26
GRAZING_COS_ALL = 0.10
"""Readings start to vanish where |cos(ray, normal)| < GRAZING_COS_START and are all gone
below GRAZING_COS_ALL."""
PIXEL_DROPOUT = 0.002
BLOBS_PER_IMAGE = 3.0


def axial_sigma_m(depth_m: np.ndarray, level: float) -> np.ndarray:
    """Standard deviation of the axial noise at depth ``depth_m`` (any shape)."""
    return level * (AXIAL_BASE_M + AXIAL_QUADRATIC_M * np.square(depth_m))


def depth_jumps(depth_m: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels with a 4-neighbour across a depth discontinuity or a hole."""
    valid = np.isfinite(depth_m)
    z = np.where(valid, depth_m, 0.0)
    jump = np.zeros(depth_m.shape, dtype=bool)
    for axis in (0, 1):
        for shift in (1, -1):
            nb = np.roll(z, shift, axis=axis)
            nb_valid = np.roll(valid, shift, axis=axis)
            thresh = np.maximum(EDGE_JUMP_MIN_M, EDGE_JUMP_FRACTION * z)
            jump |= valid & (~nb_valid | (np.abs(z - nb) > thresh))
    jump[0, :] = jump[-1, :] = False
    jump[:, 0] = jump[:, -1] = False
    return jump


def view_cosine(depth_m: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(H, W) |cos| of the angle between the view ray and the surface normal (NaN: unknown).

    Normals come from central differences of the back-projected depth map.
    """
    h, w = depth_m.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    x = (u - K[0, 2]) / K[0, 0]
    y = (v - K[1, 2]) / K[1, 1]
    pts = np.stack([x * depth_m, y * depth_m, depth_m], axis=-1)
    du = np.gradient(pts, axis=1)
    dv = np.gradient(pts, axis=0)
    normal = np.cross(du, dv)
    ray = np.stack([x, y, np.ones_like(x)], axis=-1)
    num = np.abs(np.sum(normal * ray, axis=-1))
    den = np.linalg.norm(normal, axis=-1) * np.linalg.norm(ray, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return num / den


def _smooth_field(rng: np.random.Generator, shape: tuple[int, int], sigma_px: float
                  ) -> np.ndarray:
    field = ndimage.gaussian_filter(rng.normal(size=shape), sigma_px, mode="wrap")
    return field / max(float(field.std()), 1e-12)


def observe_depth(true_depth_m: np.ndarray, K: np.ndarray, rng: np.random.Generator,
                  level: float, scale: float = 1.0, offset_m: float = 0.0) -> np.ndarray:
    """The depth map a sensor reports.

    Parameters
    ----------
    true_depth_m : (H, W) depth along the camera z axis, NaN where nothing is seen.
    K : (3, 3) intrinsics.
    level : noise level (0 = perfect, 1 = typical consumer sensor).
    scale, offset_m : systematic error, observed = true * scale + offset_m before noise.

    Returns
    -------
    (H, W) float64 metres, NaN where there is no reading.
    """
    true = np.asarray(true_depth_m, dtype=np.float64)
    out = true * scale + offset_m
    if level <= 0:
        return out
    shape = true.shape
    sigma = axial_sigma_m(out, level)
    noise = 0.8 * rng.normal(size=shape) + 0.6 * _smooth_field(rng, shape, 3.0)
    out = out + sigma * noise

    p = min(1.0, level)
    jumps = depth_jumps(true)
    ring = ndimage.binary_dilation(jumps) & ~jumps
    drop = (jumps & (rng.random(shape) < EDGE_DROP * p)) | (
        ring & (rng.random(shape) < EDGE_RING_DROP * p))

    cos = view_cosine(true, K)
    grazing = np.clip((GRAZING_COS_START - np.nan_to_num(cos, nan=1.0))
                      / (GRAZING_COS_START - GRAZING_COS_ALL), 0.0, 1.0)
    drop |= rng.random(shape) < grazing * p
    drop |= rng.random(shape) < PIXEL_DROPOUT * p

    h, w = shape
    for _ in range(int(rng.poisson(BLOBS_PER_IMAGE * p))):
        cy, cx = rng.integers(0, h), rng.integers(0, w)
        r = rng.uniform(1.0, 4.0) * max(1.0, w / 640.0)
        yy, xx = np.ogrid[0:h, 0:w]
        drop |= (yy - cy) ** 2 + (xx - cx) ** 2 <= r * r
    out[drop] = np.nan
    out[~(out > 0)] = np.nan
    return out
