"""A depth image misregistered against the colour image by a turn, as a depth-to-colour
calibration whose rotation about the optical axis is off makes it.

Frames: images are (H, W) arrays indexed ``[row, col]``, rows down; the turn is about the
image centre ``((W - 1) / 2, (H - 1) / 2)``, in degrees, positive clockwise as the image is
shown. Used to inject the effect (``scripts/bench_diagnose.py``'s ``depth_rotation``,
``scripts/edge_alignment_scan.py --turn-deg``) and in the tests of the edge test
(r2s/diagnose/stats/edge_alignment.py), which estimates the same turn.
"""

from __future__ import annotations

import numpy as np


def turned_about_centre(depth_m: np.ndarray, turn_deg: float) -> np.ndarray:
    """(H, W) ``depth_m`` turned ``turn_deg`` about the image centre (nearest pixel); what
    turns in from outside the image reads nothing (NaN)."""
    if not turn_deg:
        return depth_m
    h, w = depth_m.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    a = np.deg2rad(turn_deg)
    du, dv = u - (w - 1) / 2, v - (h - 1) / 2
    su = np.rint(np.cos(a) * du + np.sin(a) * dv + (w - 1) / 2).astype(int)
    sv = np.rint(-np.sin(a) * du + np.cos(a) * dv + (h - 1) / 2).astype(int)
    inside = (su >= 0) & (su < w) & (sv >= 0) & (sv < h)
    out = np.full(depth_m.shape, np.nan)
    out[inside] = depth_m[sv[inside], su[inside]]
    return out
