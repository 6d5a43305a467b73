"""Does the depth follow the objects' printed texture? A colour test that needs no prior.

Active depth sensors can read dark, light-absorbing surfaces too far (or too near). The
prior-based test (:mod:`r2s.diagnose.stats.colour_test`) sees it in the residual against a
registered prior; a scene without priors has none, and its completions are built from the
same depth. But an object's print (a label, a logo, text) changes its grey level over a
few pixels where its surface stays smooth, so the depth itself shows the error: a dark
letter on a light box reads as a pit.

Within small square patches of each object's mask (``patch_px``, more than ``erode_px``
inside its outline, mostly valid depth), the depth and the grey level are each fitted with
a quadratic in image position; what the quadratic leaves is the part of each that changes
within a few pixels. A smooth surface and its smooth shading are fitted by it and drop out
(the shading of a curved face, which grows darker where the face turns away and its depth
grows, would otherwise read as this effect). The depth's remainder is regressed on the
grey's over all patches of all objects: one slope, depth per unit grey. Its standard error
is taken with the patches as independent units (a sandwich estimate clustered on patches:
neighbouring pixels share a sensor's noise, its quantisation steps and the surface's
shape error, so pixels are not independent), and ``z`` = slope / error. A patch with a
depth step (a pixel more than ``OUTLIER_M`` off its quadratic, or too few valid readings)
is left out: an edge between two faces or an object's handle is shape, not print.

``|z| >= z_threshold`` is a depth error that follows the surface's colour: no catalogued
effect is that, so it is reported as unexplained structure (:data:`Z_THRESHOLD`).

Units: depth in metres, grey levels 0..1 (the mean of the colour channels), slopes in mm
per unit grey (negative: darker reads farther). Image frame: rows down, columns right.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
from scipy import ndimage

from r2s.diagnose.stats.colour_test import ColourFinding

Z_THRESHOLD = 6.0
"""Set with the scenes of docs/diagnose.md section 6 in view (``python
scripts/texture_depth_scan.py SCENE ... [--dark-mm 8]``): |z| at most 3.8 on 69 scenes
without a colour-dependent depth error; with every pixel 8 mm x (1 - luminance) too far,
|z| >= 6 on 55 of the same 69."""
PATCH_PX = 8
ERODE_PX = 3
OUTLIER_M = 0.01
MIN_FILL = 0.75
"""A patch is used when at least this share of its pixels are the object's, with depth."""
MAX_OUTLIERS = 4
MIN_PATCHES = 20
MIN_GREY_SS = 1e-3
"""The grey remainders' sum of squares over the scene below which it has no print."""


def _quadratic_remainders(rows: np.ndarray, cols: np.ndarray, values: np.ndarray
                          ) -> np.ndarray:
    """(2, N) what a quadratic in (row, col) fitted by least squares leaves of each of
    ``values`` (2, N)."""
    x = (cols - cols.mean()) / PATCH_PX
    y = (rows - rows.mean()) / PATCH_PX
    design = np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=1)
    coef, *_ = np.linalg.lstsq(design, values.T, rcond=None)
    return values - (design @ coef).T


def patch_remainders(depth_m: np.ndarray, grey: np.ndarray, own: np.ndarray,
                     patch_px: int = PATCH_PX) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per usable patch of the boolean (H, W) region ``own``: the (depth m, grey)
    remainders of its pixels after their quadratics. Patches are the image's
    ``patch_px`` grid."""
    out = []
    rows_all, cols_all = np.nonzero(own)
    if len(rows_all) == 0:
        return out
    key = (rows_all // patch_px) * 100_000 + cols_all // patch_px
    order = np.argsort(key, kind="stable")
    key, rows_all, cols_all = key[order], rows_all[order], cols_all[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    ends = np.r_[starts[1:], len(key)]
    for a, b in zip(starts, ends):
        if b - a < MIN_FILL * patch_px * patch_px:
            continue
        rows, cols = rows_all[a:b], cols_all[a:b]
        rest = _quadratic_remainders(rows, cols, np.stack([depth_m[rows, cols],
                                                           grey[rows, cols]]))
        ok = np.abs(rest[0]) < OUTLIER_M
        if np.count_nonzero(~ok) > MAX_OUTLIERS:
            continue
        if not ok.all():
            rest = _quadratic_remainders(rows[ok], cols[ok],
                                         np.stack([depth_m[rows[ok], cols[ok]],
                                                   grey[rows[ok], cols[ok]]]))
        out.append((rest[0], rest[1]))
    return out


def clustered_slope(patches: list[tuple[np.ndarray, np.ndarray]]) -> tuple[float, float]:
    """(slope, its standard error) of depth on grey through the origin over all pixels,
    the error clustered on patches; (nan, nan) without grey variation."""
    sxx = sum(float(g @ g) for _, g in patches)
    if sxx <= 0:
        return float("nan"), float("nan")
    slope = sum(float(g @ d) for d, g in patches) / sxx
    meat = sum(float(g @ (d - slope * g)) ** 2 for d, g in patches)
    return slope, float(np.sqrt(meat)) / sxx


def test_texture_depth(depth_m: np.ndarray, grey: Optional[np.ndarray], masks: np.ndarray,
                       z_threshold: float = Z_THRESHOLD, patch_px: int = PATCH_PX,
                       erode_px: int = ERODE_PX) -> Optional[ColourFinding]:
    """The test of the module docstring on a depth image (H, W) m (0 or NaN: no reading),
    its grey image (H, W) 0..1 and instance masks (H, W) (0: background). None without a
    grey image, or with fewer than ``MIN_PATCHES`` usable patches or no print on them."""
    if grey is None or depth_m is None or masks is None:
        return None
    depth = np.asarray(depth_m, dtype=np.float64)
    valid = np.isfinite(depth) & (depth > 0)
    patches: list = []
    by_object: dict[int, list] = {}
    for oid in np.unique(masks):
        if oid == 0:
            continue
        own = masks == oid
        if erode_px > 0:
            own = ndimage.binary_erosion(own, iterations=erode_px)
        found = patch_remainders(depth, np.asarray(grey, dtype=np.float64), own & valid,
                                 patch_px)
        if found:
            by_object[int(oid)] = found
            patches += found
    if len(patches) < MIN_PATCHES or sum(float(g @ g) for _, g in patches) < MIN_GREY_SS:
        return None
    slope, se = clustered_slope(patches)
    if not np.isfinite(se) or se <= 0:
        return None
    z = slope / se
    slopes, zs, points = {}, {}, {}
    for oid, own_patches in by_object.items():
        s, e = clustered_slope(own_patches)
        if np.isfinite(s) and np.isfinite(e) and e > 0 and len(own_patches) >= 3:
            slopes[oid] = s * 1000.0
            zs[oid] = s / e
            points[oid] = _binned(own_patches)
    return ColourFinding(z=float(z), z_threshold=float(z_threshold),
                         structured=abs(z) >= z_threshold, slopes_mm=slopes,
                         z_by_object=zs, points=points, source="texture",
                         scene_slope_mm=float(slope * 1000.0))


def _binned(patches: list[tuple[np.ndarray, np.ndarray]], bins: int = 12) -> tuple:
    """(grey remainder, mean depth remainder mm) in ``bins`` quantile bins of the grey
    remainder, for the picture (every pixel would be a cloud)."""
    d = np.concatenate([p[0] for p in patches])
    g = np.concatenate([p[1] for p in patches])
    edges = np.unique(np.quantile(g, np.linspace(0, 1, bins + 1)))
    idx = np.clip(np.searchsorted(edges, g, side="right") - 1, 0, len(edges) - 2)
    gx = [float(g[idx == k].mean()) for k in range(len(edges) - 1) if np.any(idx == k)]
    dy = [float(d[idx == k].mean() * 1000.0) for k in range(len(edges) - 1) if np.any(idx == k)]
    return gx, dy
