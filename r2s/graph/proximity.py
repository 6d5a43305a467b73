"""Proximity edges: object pairs whose axis-aligned bounding boxes, inflated, overlap."""

from __future__ import annotations

import numpy as np


def aabb_overlap_pairs(ids: list[int], aabbs_m: np.ndarray, margin_m: float) -> list[tuple[int, int]]:
    """Pairs (a, b), a < b, whose AABBs grown by ``margin_m`` on every side overlap.

    Parameters
    ----------
    ids : (M,) object ids.
    aabbs_m : (M, 2, 3) world min / max corners.
    margin_m : inflation of each box (two touching boxes overlap for any margin >= 0).
    """
    boxes = np.asarray(aabbs_m, dtype=np.float64).reshape(-1, 2, 3)
    lo = boxes[:, 0] - margin_m
    hi = boxes[:, 1] + margin_m
    overlap = np.all((lo[:, None, :] <= hi[None, :, :]) & (lo[None, :, :] <= hi[:, None, :]), axis=-1)
    pairs = []
    for i in range(len(ids)):
        for j in range(i + 1, len(ids)):
            if overlap[i, j]:
                a, b = sorted((int(ids[i]), int(ids[j])))
                pairs.append((a, b))
    return sorted(pairs)
