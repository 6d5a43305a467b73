"""Bilinear texture lookups as fixed (index, weight) footprints.

With fixed geometry every pixel's UV is fixed, so a lookup is a weighted sum of four texels
whose indices and weights are computed once; the texture itself may then change (the
torch optimiser in :mod:`r2s.texture.refine` gathers with the same footprints).

Conventions (trimesh's UV convention, see :mod:`r2s.texture.uv`): texel ``(row, col)`` of an
(H, W) texture has its centre at ``u = (col + 0.5) / W``, ``v = 1 - (row + 0.5) / H``;
lookups outside [0, 1] repeat the texture (glTF's default sampler).
"""

from __future__ import annotations

import numpy as np


def uv_to_texel(uv: np.ndarray, height: int, width: int) -> np.ndarray:
    """(N, 2) continuous ``(col, row)`` texel coordinates (centres at integers) of UVs (N, 2)."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    return np.stack([uv[:, 0] * width - 0.5, (1.0 - uv[:, 1]) * height - 0.5], axis=1)


def bilinear_footprint(uv: np.ndarray, height: int, width: int
                       ) -> tuple[np.ndarray, np.ndarray]:
    """The four texels and weights of a bilinear lookup at each UV.

    Parameters
    ----------
    uv : (N, 2) texture coordinates.
    height, width : texture size in texels.

    Returns
    -------
    index : (N, 4) int64 flat texel indices ``row * width + col`` (wrapped into range).
    weight : (N, 4) float32 weights summing to 1.
    """
    xy = uv_to_texel(uv, height, width)
    x0 = np.floor(xy[:, 0])
    y0 = np.floor(xy[:, 1])
    fx = (xy[:, 0] - x0)[:, None]
    fy = (xy[:, 1] - y0)[:, None]
    x0 = x0.astype(np.int64)
    y0 = y0.astype(np.int64)
    cols = np.stack([x0, x0 + 1, x0, x0 + 1], axis=1) % width
    rows = np.stack([y0, y0, y0 + 1, y0 + 1], axis=1) % height
    weight = np.concatenate([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], axis=1)
    return rows * width + cols, weight.astype(np.float32)


def sample(texture: np.ndarray, index: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """(N, C) float64 values of an (H, W, C) texture at :func:`bilinear_footprint` footprints."""
    flat = np.asarray(texture, dtype=np.float64).reshape(-1, texture.shape[-1])
    return np.einsum("nk,nkc->nc", weight.astype(np.float64), flat[index])
