"""How well the pixel colours of one image region are found among another's.

Two regions of one surface hold the same colours even where their mean colours differ
(a printed box cut through its print); used by the tests of mask ids that are pieces of
one object (:mod:`r2s.geometry.mask_fragments`, :mod:`r2s.geometry.occluded_fragments`).
Colours are RGB, 0-255; distances Euclidean.
"""

from __future__ import annotations

import numpy as np


def nearest_colour_distances(a: np.ndarray, b: np.ndarray, samples: int
                             ) -> tuple[np.ndarray, np.ndarray]:
    """(distance from each of (N, 3) colours ``a`` to the nearest of (M, 3) ``b``, and from
    each of ``b`` to the nearest of ``a``), each side thinned first to at most ``samples``
    colours (every k-th: the distances shrink as samples grow, so both sides are capped
    alike)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    a = a[::max(1, -(-len(a) // samples))]
    b = b[::max(1, -(-len(b) // samples))]
    d = np.sqrt(((a[:, None, :] - b[None, :, :]) ** 2).sum(axis=2))
    return d.min(axis=1), d.min(axis=0)
