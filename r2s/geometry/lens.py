"""Radial lens distortion (Brown's model, two terms) and image resampling through it.

Normalised image coordinates ``x = K^-1 [u, v, 1]`` (ideal pinhole, z = 1) are distorted as

    x_d = x * (1 + k1 r^2 + k2 r^4),   r^2 = x_x^2 + x_y^2,

so ``k1 < 0`` is barrel distortion (the periphery is pulled towards the principal point).
A depth image of a distorted camera stores at pixel ``x_d`` the camera-z depth of the point
seen along the ideal ray ``x``; the depth value itself is not changed, only where it lands.

Brown's decentering (tangential) terms p1, p2 of a lens mounted off the sensor's axis are
here too (:func:`decentering_offset`, :func:`undistort_decentred`). The diagnose catalogue's
lens does not fit them (docs/diagnose.md, section 10, ``lens+tangential``); the benchmark
injects them and measures what fitting them would do.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage


def radial_factor(r2: np.ndarray, k1: float, k2: float = 0.0) -> np.ndarray:
    """``1 + k1 r^2 + k2 r^4`` for squared normalised radii ``r2`` (any shape)."""
    r2 = np.asarray(r2, dtype=np.float64)
    return 1.0 + k1 * r2 + k2 * r2 * r2


def undistort_normalised(xd: np.ndarray, k1: float, k2: float = 0.0,
                         iterations: int = 8) -> np.ndarray:
    """(N, 2) ideal normalised coordinates of distorted ones ``xd`` (fixed-point iteration;
    converges for the mild distortions of real RGB-D lenses, |k1| r^2 < 0.3)."""
    xd = np.asarray(xd, dtype=np.float64)
    x = xd.copy()
    for _ in range(iterations):
        x = xd / radial_factor(np.sum(x * x, axis=-1), k1, k2)[..., None]
    return x


def decentering_offset(x: np.ndarray, p1: float, p2: float) -> np.ndarray:
    """(N, 2) decentering displacement of normalised coordinates ``x`` (N, 2):
    (2 p1 x y + p2 (r^2 + 2 x^2), p1 (r^2 + 2 y^2) + 2 p2 x y)."""
    x = np.asarray(x, dtype=np.float64)
    u, v = x[:, 0], x[:, 1]
    r2 = u * u + v * v
    return np.stack([2 * p1 * u * v + p2 * (r2 + 2 * u * u),
                     p1 * (r2 + 2 * v * v) + 2 * p2 * u * v], axis=1)


def undistort_decentred(xd: np.ndarray, k1: float, p1: float, p2: float,
                        iterations: int = 15) -> np.ndarray:
    """(N, 2) ideal normalised coordinates x whose distortion
    ``x (1 + k1 r^2) + decentering_offset(x)`` is ``xd`` (N, 2), by fixed-point iteration."""
    xd = np.asarray(xd, dtype=np.float64)
    x = xd.copy()
    for _ in range(iterations):
        factor = radial_factor(np.sum(x * x, axis=-1), k1)
        x = (xd - decentering_offset(x, p1, p2)) / factor[:, None]
    return x


def distort_normalised(x: np.ndarray, k1: float, k2: float = 0.0) -> np.ndarray:
    """(N, 2) distorted normalised coordinates of ideal ones ``x``."""
    x = np.asarray(x, dtype=np.float64)
    return x * radial_factor(np.sum(x * x, axis=-1), k1, k2)[..., None]


def _pixel_grid(K: np.ndarray, height: int, width: int) -> np.ndarray:
    """(H*W, 2) normalised coordinates of every pixel centre."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    Ki = np.linalg.inv(np.asarray(K, dtype=np.float64))
    pts = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], axis=1) @ Ki.T
    return pts[:, :2]


def _to_pixels(K: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    K = np.asarray(K, dtype=np.float64)
    u = K[0, 0] * x[:, 0] + K[0, 1] * x[:, 1] + K[0, 2]
    v = K[1, 1] * x[:, 1] + K[1, 2]
    return v, u


def _sample(image: np.ndarray, rows: np.ndarray, cols: np.ndarray, nearest: bool,
            fill: float) -> np.ndarray:
    img = np.asarray(image)
    h, w = img.shape[:2]
    order = 0 if nearest else 1
    out_shape = (h, w) + img.shape[2:]
    if img.ndim == 2:
        planes = [img]
    else:
        planes = [img[..., c] for c in range(img.shape[2])]
    res = []
    for p in planes:
        src = p.astype(np.float64)
        if nearest:
            r = np.rint(rows).astype(np.int64)
            c = np.rint(cols).astype(np.int64)
            ok = (r >= 0) & (r < h) & (c >= 0) & (c < w)
            vals = np.full(rows.shape, fill, dtype=np.float64)
            vals[ok] = src[r[ok], c[ok]]
        else:
            ok = (rows >= -0.5) & (rows <= h - 0.5) & (cols >= -0.5) & (cols <= w - 0.5)
            vals = ndimage.map_coordinates(np.nan_to_num(src, nan=fill), [rows, cols],
                                           order=order, mode="nearest")
            vals[~ok] = fill
        res.append(vals.reshape(h, w))
    out = res[0] if img.ndim == 2 else np.stack(res, axis=-1)
    return out.reshape(out_shape)


def distort_image(image: np.ndarray, K: np.ndarray, k1: float, k2: float = 0.0,
                  nearest: bool = True, fill: float = np.nan) -> np.ndarray:
    """What a camera with distortion (k1, k2) records, from an ideal pinhole ``image``
    (H, W[, C]) of the same intrinsics ``K``: output pixel ``x_d`` takes the ideal image at
    ``x = undistort(x_d)``. ``nearest`` for depth and label images (no blending across
    edges), bilinear otherwise; pixels whose source lies outside the image get ``fill``."""
    h, w = np.asarray(image).shape[:2]
    x = undistort_normalised(_pixel_grid(K, h, w), k1, k2)
    rows, cols = _to_pixels(K, x)
    return _sample(image, rows, cols, nearest, fill).astype(np.asarray(image).dtype)


def undistort_image(image: np.ndarray, K: np.ndarray, k1: float, k2: float = 0.0,
                    nearest: bool = True, fill: float = np.nan) -> np.ndarray:
    """The ideal pinhole image from a distorted one (inverse of :func:`distort_image`):
    output pixel ``x`` takes the recorded image at ``x_d = distort(x)``."""
    h, w = np.asarray(image).shape[:2]
    xd = distort_normalised(_pixel_grid(K, h, w), k1, k2)
    rows, cols = _to_pixels(K, xd)
    return _sample(image, rows, cols, nearest, fill).astype(np.asarray(image).dtype)
