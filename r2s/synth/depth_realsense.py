"""A RealSense-like active-stereo depth sensor (``depth_model=realsense``).

What the camera reports for a true depth map, at noise level 1 (``level`` scales the
noise and every dropout probability; 0 is a perfect sensor):

- axial noise with standard deviation ``sigma_z = a * z^2`` (``a`` = :data:`AXIAL_A_PER_M`,
  2 mm at 1 m), partly spatially correlated;
- quantisation in disparity ``d = f * b / z`` to steps of ``1 / SUBPIXEL_STEPS`` pixel, so
  that the depth steps grow as ``z^2 / (f * b * SUBPIXEL_STEPS)``;
- stereo shadows: background pixels the second imager (``BASELINE_M`` to the right along
  the camera x axis) cannot see, left of every nearer surface, as wide as the disparity jump;
- holes at depth edges (a band of ``EDGE_BAND_PX`` pixels around every discontinuity), on
  dark pixels (low albedo gives no texture and no IR return), on specular surfaces (a
  glossy object's pixels that face the camera), on thin structures (parts of an object
  narrower than ``THIN_WIDTH_PX``) and on grazing surfaces;
- flying pixels: some edge pixels read a depth between the near and the far side.

:func:`observe` returns the depth and a per-pixel code of why a reading is missing or
flying (:data:`CAUSES`), which the generator writes into gt/ so that a benchmark can tell
what was injected.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from r2s.synth import depth_noise

AXIAL_A_PER_M = 0.002
"""sigma_z = AXIAL_A_PER_M * z^2 (z in metres) at noise level 1."""
BASELINE_M = 0.05
SUBPIXEL_STEPS = 16
"""Disparity is reported in steps of 1 / SUBPIXEL_STEPS pixel."""
EDGE_BAND_PX = 1
EDGE_DROP = 0.6
FLYING = 0.35
"""Share of the edge pixels that keep a reading which reads a mixed (flying) depth."""
DARK_LUMINANCE = 60.0
DARK_DROP = 0.6
"""A pixel of luminance L < DARK_LUMINANCE (0-255) has no reading with probability
DARK_DROP * (1 - L / DARK_LUMINANCE)."""
SATURATED_LUMINANCE = 245.0
GLOSSY_OBJECT = 0.3
"""Chance that an object is glossy: its pixels facing the camera (|cos| > SPECULAR_COS)
have no reading with probability SPECULAR_DROP."""
SPECULAR_COS = 0.97
SPECULAR_DROP = 0.8
THIN_WIDTH_PX = 5
THIN_DROP = 0.7
PIXEL_DROPOUT = 0.002

CAUSES: dict[str, int] = {"shadow": 1, "edge": 2, "dark": 3, "specular": 4, "thin": 5,
                          "grazing": 6, "random": 7, "flying": 8}
"""Codes of gt/realism/depth_causes.png (0: a valid reading; 8: a reading, but flying)."""


@dataclass(frozen=True)
class SensorFrame:
    """``depth_m`` (H, W) float64 metres, NaN = no reading; ``cause`` (H, W) uint8 codes of
    :data:`CAUSES`; ``counts`` pixels per cause."""

    depth_m: np.ndarray
    cause: np.ndarray
    counts: dict[str, int]


def depth_step_m(depth_m: np.ndarray | float, fx_px: float) -> np.ndarray | float:
    """The depth quantisation step at ``depth_m``: z^2 / (fx * b * SUBPIXEL_STEPS)."""
    return np.square(depth_m) / (fx_px * BASELINE_M * SUBPIXEL_STEPS)


def quantise(depth_m: np.ndarray, fx_px: float) -> np.ndarray:
    """Depth rounded to the nearest reportable disparity (NaN stays NaN)."""
    fb = fx_px * BASELINE_M
    with np.errstate(divide="ignore", invalid="ignore"):
        disparity = np.round(fb / depth_m * SUBPIXEL_STEPS) / SUBPIXEL_STEPS
        return np.where(disparity > 0, fb / disparity, np.nan)


def stereo_shadow(true_depth_m: np.ndarray, fx_px: float) -> np.ndarray:
    """(H, W) bool: pixels the second imager (to the right) does not see.

    A pixel at column u and depth z appears at column u - f b / z there; it is hidden when
    some pixel to its right in the same row lands at or left of it (a nearer surface).
    """
    valid = np.isfinite(true_depth_m)
    cols = np.arange(true_depth_m.shape[1], dtype=np.float64)[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        x_right = np.where(valid, cols - fx_px * BASELINE_M / true_depth_m, np.inf)
    # running minimum over the pixels strictly to the right
    rev_min = np.minimum.accumulate(x_right[:, ::-1], axis=1)[:, ::-1]
    right_min = np.concatenate([rev_min[:, 1:], np.full((len(x_right), 1), np.inf)], axis=1)
    return valid & (x_right > right_min + 0.5)


def thin_parts(segment: np.ndarray, width_px: int = THIN_WIDTH_PX) -> np.ndarray:
    """(H, W) bool: pixels of an object region (segment >= 0) that a disk of diameter
    ``width_px`` does not fit in (a morphological opening removes them)."""
    r = width_px / 2.0
    yy, xx = np.mgrid[-int(r):int(r) + 1, -int(r):int(r) + 1]
    disk = xx ** 2 + yy ** 2 <= r * r
    out = np.zeros(segment.shape, dtype=bool)
    for k in np.unique(segment):
        if k < 0:
            continue
        region = segment == k
        out |= region & ~ndimage.binary_opening(region, structure=disk)
    return out


def luminance(rgb: np.ndarray) -> np.ndarray:
    """(H, W) Rec. 601 luma of an (H, W, 3) uint8 image, 0-255."""
    rgb = np.asarray(rgb, dtype=np.float64)
    return 0.299 * rgb[..., 0] + 0.587 * rgb[..., 1] + 0.114 * rgb[..., 2]


def observe(true_depth_m: np.ndarray, K: np.ndarray, rgb: np.ndarray, segment: np.ndarray,
            rng: np.random.Generator, level: float = 1.0, scale: float = 1.0,
            offset_m: float = 0.0) -> SensorFrame:
    """The depth a RealSense-like sensor reports.

    Parameters
    ----------
    true_depth_m : (H, W) depth along the camera z axis, NaN where nothing is seen.
    K : (3, 3) intrinsics.
    rgb : (H, W, 3) uint8 rendered colour (for dark and saturated pixels).
    segment : (H, W) int index of the object seen at each pixel, -1 for table/background.
    level : noise level; scale, offset_m : systematic error applied first.
    """
    true = np.asarray(true_depth_m, dtype=np.float64)
    shape = true.shape
    out = true * scale + offset_m
    cause = np.zeros(shape, dtype=np.uint8)
    if level <= 0:
        return SensorFrame(out, cause, {name: 0 for name in CAUSES})
    fx = float(K[0, 0])
    p = min(1.0, level)
    valid = np.isfinite(true)

    noise = 0.8 * rng.normal(size=shape) + 0.6 * depth_noise._smooth_field(rng, shape, 3.0)
    out = out + level * AXIAL_A_PER_M * np.square(out) * noise
    out = quantise(out, fx)

    # flying pixels: a mix of the near and the far side of an edge
    jumps = depth_noise.depth_jumps(true)
    filled = np.where(valid, true, np.nanmax(true) if valid.any() else 0.0)
    near = ndimage.grey_erosion(filled, size=(3, 3))
    far = ndimage.grey_dilation(np.where(valid, true, 0.0), size=(3, 3))
    flying = jumps & (rng.random(shape) < FLYING * p)
    mix = rng.uniform(0.15, 0.85, size=shape)
    out = np.where(flying, (near + mix * (far - near)) * scale + offset_m, out)
    cause[flying] = CAUSES["flying"]

    band = ndimage.binary_dilation(jumps, iterations=EDGE_BAND_PX) if EDGE_BAND_PX else jumps
    cos = depth_noise.view_cosine(true, K)
    grazing = np.clip((depth_noise.GRAZING_COS_START - np.nan_to_num(cos, nan=1.0))
                      / (depth_noise.GRAZING_COS_START - depth_noise.GRAZING_COS_ALL), 0, 1)
    grazing[jumps] = 0.0  # a normal across a discontinuity is meaningless: edges are above
    lum = luminance(rgb)
    dark = DARK_DROP * np.clip(1.0 - lum / DARK_LUMINANCE, 0.0, 1.0)
    glossy_ids = [k for k in np.unique(segment) if k >= 0 and rng.random() < GLOSSY_OBJECT]
    glossy = np.isin(segment, glossy_ids)
    specular = (glossy & (np.nan_to_num(cos, nan=0.0) > SPECULAR_COS)) \
        | (lum >= SATURATED_LUMINANCE)
    thin = thin_parts(segment)
    # later causes overwrite earlier ones in the record; any one of them drops the pixel
    drops = [
        ("random", rng.random(shape) < PIXEL_DROPOUT * p),
        ("grazing", rng.random(shape) < grazing * p),
        ("thin", thin & (rng.random(shape) < THIN_DROP * p)),
        ("specular", specular & (rng.random(shape) < SPECULAR_DROP * p)),
        ("dark", rng.random(shape) < dark * p),
        ("edge", band & (rng.random(shape) < EDGE_DROP * p)),
        ("shadow", stereo_shadow(true, fx) if p > 0 else np.zeros(shape, bool)),
    ]
    dropped = np.zeros(shape, dtype=bool)
    for name, mask in drops:
        mask = mask & valid
        cause[mask] = CAUSES[name]
        dropped |= mask
    out[dropped] = np.nan
    out[~(out > 0)] = np.nan
    cause[~valid] = 0
    counts = {name: int(np.sum(cause == code)) for name, code in CAUSES.items()}
    return SensorFrame(out, cause, counts)
