"""Do the depth image's edges sit on the masks' edges? A test of depth-to-colour registration.

An RGB-D sensor measures depth with one camera and colour with another; the depth image is
resampled into the colour camera with a calibration that can be off by a few pixels. The
instance masks come from the colour image, so the depth then lies shifted against them:
one side of every object reads the table behind it, the other side's table pixels read
the object. No catalogued effect is this (it moves no 3-D point; it mixes up whose point
is whose), so it is reported as unexplained structure when found.

Where an object occludes something farther away, its mask's outline and a depth jump
coincide. Per object, the mask's inner outline ``B`` (mask pixels with a 4-neighbour
outside the mask) is correlated with the depth image's near-side edges ``E`` (valid pixels
whose next valid reading in one of the 4 directions, within ``GAP_PX``, is at least
``jump_m`` farther; edges inside another instance's mask are that instance's and left out)
over integer shifts within ``max_shift_px``:

    C(dx, dy) = number of outline pixels p with E(p + (dx, dy))

The location of the correlation's top (the value-weighted centroid of the shifts that reach
``TOP_FRACTION`` of its maximum) is where the depth image's edges lie relative to the
outline (+x right, +y down, pixels). A mask that bleeds or is eroded by d pixels on all
sides makes a ring of equal tops around zero whose centroid stays at zero; a depth image
shifted by s moves the top to s. The scene's estimate is the top of the correlations
summed over the objects; each object's own top is kept too. The spread comes from a
bootstrap over objects (resampled with replacement, ``bootstrap`` times; reported). The
test reports structure when the shift along its larger axis is at least ``min_shift_px``
and at least ``min_agreement`` of the objects agree: their own shift lies on the same
side, at least half as far. One object whose outline meets another object's edges can
pull the summed top a little, but not the others' tops.

Thresholds (docs/diagnose.md, section 6; set with those scenes in view, nothing held out):
without a shift the estimate reached 1.0 px on 19 clean 320x240 benchmark-like scenes and
0.94 px on 22 scenes with segmenter masks or the seed demo's (640x480, one 1280x720); with
the depth image moved 3 px right it read 1.8-4.0 px, and at least 71 % of the objects agreed
(``python scripts/edge_alignment_scan.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

MAX_SHIFT_PX = 6
JUMP_M = 0.02
"""A depth step of at least this is an edge (an object standing in front of the table or of
another object)."""
GAP_PX = 3
"""Readings lost along an edge (up to this many pixels) are skipped."""
MIN_OUTLINE_PX = 10
"""An object with fewer outline pixels on depth edges at its best shift says nothing."""
TOP_FRACTION = 0.8
MIN_OBJECTS = 3
MIN_SHIFT_PX = 1.5
MIN_AGREEMENT = 0.6
BOOTSTRAP = 200


@dataclass(frozen=True)
class EdgeFinding:
    """Outcome of :func:`test_edge_alignment` (JSON-able through :meth:`summary`).

    shift_px : (dx, dy), where the depth edges lie relative to the mask edges (+x right,
        +y down); sd_px : its bootstrap standard deviation per axis; z : the larger of
        |shift| / sd over the two axes; agreement : the share of objects that agree (module
        docstring); peaks_px : per object id, its own peak shift;
    correlation : (2 S + 1, 2 S + 1) summed correlation, rows dy = -S..S, columns dx.
    """

    shift_px: tuple[float, float]
    sd_px: tuple[float, float]
    z: float
    agreement: float
    min_agreement: float
    min_shift_px: float
    structured: bool
    peaks_px: dict = field(default_factory=dict)
    correlation: Optional[np.ndarray] = field(default=None, repr=False)

    @property
    def pattern(self) -> str:
        dx, dy = self.shift_px
        return (f"the depth image's edges lie {abs(dx):.1f} px "
                f"{'right' if dx >= 0 else 'left'} and {abs(dy):.1f} px "
                f"{'down' if dy >= 0 else 'up'} of the masks' edges ({self.agreement:.0%} of "
                f"{len(self.peaks_px)} objects agree): the depth and colour images are "
                "misregistered")

    def summary(self) -> dict:
        return {"test": "edge alignment", "structured": self.structured,
                "shift_px": list(self.shift_px), "sd_px": list(self.sd_px), "z": self.z,
                "agreement": self.agreement, "min_agreement": self.min_agreement,
                "min_shift_px": self.min_shift_px,
                "peaks_px": {str(k): list(v) for k, v in self.peaks_px.items()},
                "best_feature": "depth-to-colour shift", "pattern": self.pattern}


def near_edges(depth_m: np.ndarray, jump_m: float = JUMP_M, gap_px: int = GAP_PX
               ) -> np.ndarray:
    """(H, W) bool: valid pixels whose next valid reading in one of the 4 directions, within
    ``gap_px`` pixels (sensors lose the readings along depth edges), is at least ``jump_m``
    farther."""
    d = np.where(np.isfinite(depth_m) & (depth_m > 0), depth_m, np.nan)
    h, w = d.shape
    edge = np.zeros(d.shape, dtype=bool)
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        nxt = np.full(d.shape, np.nan)
        for k in range(gap_px, 0, -1):  # the nearest valid one wins: fill far to near
            shifted = np.full(d.shape, np.nan)
            ys, yd = (slice(k * dy, h), slice(0, h - k * dy)) if dy >= 0 else \
                (slice(0, h + k * dy), slice(-k * dy, h))
            xs, xd = (slice(k * dx, w), slice(0, w - k * dx)) if dx >= 0 else \
                (slice(0, w + k * dx), slice(-k * dx, w))
            shifted[yd, xd] = d[ys, xs]
            nxt = np.where(np.isfinite(shifted), shifted, nxt)
        with np.errstate(invalid="ignore"):
            edge |= nxt - d >= jump_m
    return edge


def inner_outline(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels of ``mask`` with a 4-neighbour outside it (image border: inside)."""
    m = np.asarray(mask, dtype=bool)
    inside = m.copy()
    inside[:, :-1] &= m[:, 1:]
    inside[:, 1:] &= m[:, :-1]
    inside[:-1, :] &= m[1:, :]
    inside[1:, :] &= m[:-1, :]
    return m & ~inside


def outline_correlation(outline: np.ndarray, edges: np.ndarray, max_shift_px: int
                        ) -> np.ndarray:
    """(2 S + 1, 2 S + 1) counts of outline pixels p with ``edges[p + (dy, dx)]``; rows
    dy = -S..S, columns dx = -S..S."""
    s = int(max_shift_px)
    rows, cols = np.nonzero(outline)
    h, w = edges.shape
    out = np.zeros((2 * s + 1, 2 * s + 1))
    for iy, dy in enumerate(range(-s, s + 1)):
        for ix, dx in enumerate(range(-s, s + 1)):
            r, c = rows + dy, cols + dx
            ok = (r >= 0) & (r < h) & (c >= 0) & (c < w)
            out[iy, ix] = edges[r[ok], c[ok]].sum()
    return out


def top_location(corr: np.ndarray) -> tuple[float, float]:
    """(dx, dy): value-weighted centroid of the shifts where ``corr`` reaches
    ``TOP_FRACTION`` of its maximum."""
    s = corr.shape[0] // 2
    top = corr >= TOP_FRACTION * corr.max()
    dy, dx = np.nonzero(top)
    weight = corr[top]
    return (float(np.sum((dx - s) * weight) / weight.sum()),
            float(np.sum((dy - s) * weight) / weight.sum()))


def test_edge_alignment(depth_m: np.ndarray, masks: np.ndarray,
                        min_shift_px: float = MIN_SHIFT_PX,
                        min_agreement: float = MIN_AGREEMENT,
                        max_shift_px: int = MAX_SHIFT_PX, jump_m: float = JUMP_M,
                        bootstrap: int = BOOTSTRAP, seed: int = 0) -> Optional[EdgeFinding]:
    """The test of the module docstring. ``depth_m`` (H, W) metres, NaN = no reading;
    ``masks`` (H, W) instance ids, 0 = none. None when fewer than ``MIN_OBJECTS`` objects
    have at least ``MIN_OUTLINE_PX`` outline pixels on depth edges."""
    edges = near_edges(depth_m, jump_m)
    per_object: dict[int, np.ndarray] = {}
    for oid in np.unique(masks):
        if oid <= 0:
            continue
        own_edges = edges & ((masks == 0) | (masks == oid))  # not a neighbour's outline
        corr = outline_correlation(inner_outline(masks == oid), own_edges, max_shift_px)
        if corr.max() >= MIN_OUTLINE_PX:
            per_object[int(oid)] = corr
    if len(per_object) < MIN_OBJECTS:
        return None
    ids = sorted(per_object)
    stack = np.stack([per_object[i] for i in ids])
    total = stack.sum(axis=0)
    shift = np.array(top_location(total))
    rng = np.random.default_rng(seed)
    draws = np.array([top_location(stack[rng.integers(0, len(ids), len(ids))].sum(axis=0))
                      for _ in range(bootstrap)])
    sd = np.maximum(draws.std(axis=0), 0.1)  # a tenth of a pixel: the top's resolution
    peaks = {i: top_location(per_object[i]) for i in ids}
    axis = int(np.argmax(np.abs(shift)))
    agreement = sum(1 for p in peaks.values() if p[axis] * shift[axis] > 0
                    and abs(p[axis]) >= 0.5 * abs(shift[axis])) / len(ids)
    structured = bool(abs(shift[axis]) >= min_shift_px and agreement >= min_agreement)
    return EdgeFinding(shift_px=(round(float(shift[0]), 3), round(float(shift[1]), 3)),
                       sd_px=(round(float(sd[0]), 3), round(float(sd[1]), 3)),
                       z=round(float(np.max(np.abs(shift) / sd)), 3),
                       agreement=round(agreement, 3), min_agreement=float(min_agreement),
                       min_shift_px=float(min_shift_px), structured=structured,
                       peaks_px={i: (round(p[0], 2), round(p[1], 2)) for i, p in peaks.items()},
                       correlation=total)
