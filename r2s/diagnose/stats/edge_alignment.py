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

A depth image turned against the colour image (a registration whose rotation about the
optical axis is off) moves each object's edges across its radius from the image centre: by
about the angle times that radius, in directions that cancel in the sum over objects. So
the correlation is also taken with the outline turned by ``theta`` about the image centre
before it is shifted, for ``theta`` within ``MAX_TURN_DEG`` in steps of ``TURN_STEP_DEG``:
``C(theta, dx, dy)``. The turn is the location in ``theta`` of the top of that volume
(again the weighted centroid of the cells within ``TOP_FRACTION`` of its maximum; a
bleeding mask's ring of tops is symmetric in ``theta`` too). It is reported when it is at
least ``min_turn_deg`` and turning raises the best count by at least ``MIN_TURN_GAIN``
over the best unturned one (a flat profile says nothing about a turn).

Thresholds (docs/diagnose.md, section 6; set with those scenes in view, nothing held out):
without a shift the estimate reached 1.0 px on 19 clean 320x240 benchmark-like scenes and
0.94 px on 22 scenes with segmenter masks or the seed demo's (640x480, one 1280x720); with
the depth image moved 3 px right it read 1.8-4.0 px, and at least 71 % of the objects agreed
(``python scripts/edge_alignment_scan.py``). The turn: on 19 clean 320x240 scenes and 69
scenes with segmenter masks it read at most 0.33 deg where turning raised the count by 10 %
or more (by at most 18 %), and 1.08 deg once where it raised it by 1 %; with the depth
image turned 1.5 deg it read 0.81-1.79 deg and was reported in 57 of 58 scenes
(``python scripts/edge_alignment_scan.py --turn-deg 1.5``).
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
TURN_STEP_DEG = 0.25
MAX_TURN_DEG = 3.0
MIN_TURN_DEG = 0.75
MIN_TURN_GAIN = 1.10
"""A turn is reported only where the best count over the turns is at least this times the
best unturned count."""


@dataclass(frozen=True)
class EdgeFinding:
    """Outcome of :func:`test_edge_alignment` (JSON-able through :meth:`summary`).

    shift_px : (dx, dy), where the depth edges lie relative to the mask edges (+x right,
        +y down); sd_px : its bootstrap standard deviation per axis; z : the larger of
        |shift| / sd over the two axes; agreement : the share of objects that agree (module
        docstring); peaks_px : per object id, its own peak shift;
    correlation : (2 S + 1, 2 S + 1) summed correlation, rows dy = -S..S, columns dx.
    turn_deg : the depth image's turn against the masks about the image centre (degrees,
        + clockwise as the image is shown, rows down); turn_sd_deg : its bootstrap standard
        deviation; turn_gain : the best count over the turns over the best unturned one;
        turn_structured : the turn passed ``min_turn_deg`` and ``MIN_TURN_GAIN``;
    turn_profile : (T, 2) per turn (degrees), the best count over the shifts.
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
    turn_deg: float = 0.0
    turn_sd_deg: float = 0.0
    turn_gain: float = 1.0
    min_turn_deg: float = MIN_TURN_DEG
    turn_structured: bool = False
    turn_profile: Optional[np.ndarray] = field(default=None, repr=False)

    @property
    def pattern(self) -> str:
        dx, dy = self.shift_px
        if self.turn_structured and not self.shift_structured:
            return (f"the depth image's edges lie turned {abs(self.turn_deg):.1f} deg "
                    f"{'clockwise' if self.turn_deg >= 0 else 'counter-clockwise'} about the "
                    f"image centre against the masks' edges (turned, {self.turn_gain - 1:.0%} "
                    "more outline pixels meet a depth edge): the depth and colour images are "
                    "misregistered")
        return (f"the depth image's edges lie {abs(dx):.1f} px "
                f"{'right' if dx >= 0 else 'left'} and {abs(dy):.1f} px "
                f"{'down' if dy >= 0 else 'up'} of the masks' edges ({self.agreement:.0%} of "
                f"{len(self.peaks_px)} objects agree): the depth and colour images are "
                "misregistered")

    @property
    def shift_structured(self) -> bool:
        """The shift alone passed (the finding is ``structured`` when the shift or the turn
        did)."""
        axis = int(np.argmax(np.abs(self.shift_px)))
        return bool(abs(self.shift_px[axis]) >= self.min_shift_px
                    and self.agreement >= self.min_agreement)

    def summary(self) -> dict:
        return {"test": "edge alignment", "structured": self.structured,
                "turn_deg": self.turn_deg, "turn_sd_deg": self.turn_sd_deg,
                "turn_gain": self.turn_gain, "min_turn_deg": self.min_turn_deg,
                "turn_structured": self.turn_structured,
                "shift_px": list(self.shift_px), "sd_px": list(self.sd_px), "z": self.z,
                "agreement": self.agreement, "min_agreement": self.min_agreement,
                "min_shift_px": self.min_shift_px,
                "peaks_px": {str(k): list(v) for k, v in self.peaks_px.items()},
                "best_feature": ("depth-to-colour turn" if self.turn_structured
                                 and not self.shift_structured else "depth-to-colour shift"),
                "pattern": self.pattern}


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


def outline_correlation(outline: np.ndarray, edges: np.ndarray, max_shift_px: int,
                        turn_deg: float = 0.0) -> np.ndarray:
    """(2 S + 1, 2 S + 1) counts of outline pixels p with ``edges[q + (dy, dx)]``, q = p
    turned ``turn_deg`` about the image centre (+ clockwise as shown, rows down; nearest
    pixel); rows dy = -S..S, columns dx = -S..S."""
    s = int(max_shift_px)
    rows, cols = np.nonzero(outline)
    h, w = edges.shape
    if turn_deg:
        a = np.deg2rad(turn_deg)
        du, dv = cols - (w - 1) / 2, rows - (h - 1) / 2
        cols = np.rint((w - 1) / 2 + np.cos(a) * du - np.sin(a) * dv).astype(int)
        rows = np.rint((h - 1) / 2 + np.sin(a) * du + np.cos(a) * dv).astype(int)
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


def _turn_top(volume: np.ndarray, turns_deg: np.ndarray) -> float:
    """The turn (degrees) of the top of a (T, 2 S + 1, 2 S + 1) correlation volume: the
    value-weighted mean turn of its cells within ``TOP_FRACTION`` of its maximum."""
    top = volume >= TOP_FRACTION * volume.max()
    weight = volume[top]
    return float(np.sum(turns_deg[np.nonzero(top)[0]] * weight) / weight.sum())


def test_edge_alignment(depth_m: np.ndarray, masks: np.ndarray,
                        min_shift_px: float = MIN_SHIFT_PX,
                        min_agreement: float = MIN_AGREEMENT,
                        max_shift_px: int = MAX_SHIFT_PX, jump_m: float = JUMP_M,
                        bootstrap: int = BOOTSTRAP, seed: int = 0,
                        min_turn_deg: float = MIN_TURN_DEG) -> Optional[EdgeFinding]:
    """The test of the module docstring. ``depth_m`` (H, W) metres, NaN = no reading;
    ``masks`` (H, W) instance ids, 0 = none. None when fewer than ``MIN_OBJECTS`` objects
    have at least ``MIN_OUTLINE_PX`` outline pixels on depth edges."""
    edges = near_edges(depth_m, jump_m)
    n_turn = int(round(MAX_TURN_DEG / TURN_STEP_DEG))
    turns = TURN_STEP_DEG * np.arange(-n_turn, n_turn + 1)
    per_object: dict[int, np.ndarray] = {}
    for oid in np.unique(masks):
        if oid <= 0:
            continue
        own_edges = edges & ((masks == 0) | (masks == oid))  # not a neighbour's outline
        outline = inner_outline(masks == oid)
        corr = outline_correlation(outline, own_edges, max_shift_px)
        if corr.max() >= MIN_OUTLINE_PX:
            per_object[int(oid)] = np.stack([
                corr if t == 0 else outline_correlation(outline, own_edges, max_shift_px, t)
                for t in turns])
    if len(per_object) < MIN_OBJECTS:
        return None
    ids = sorted(per_object)
    volumes = np.stack([per_object[i] for i in ids])  # (objects, T, 2 S + 1, 2 S + 1)
    stack = volumes[:, n_turn]
    total = stack.sum(axis=0)
    shift = np.array(top_location(total))
    rng = np.random.default_rng(seed)
    picks = [rng.integers(0, len(ids), len(ids)) for _ in range(bootstrap)]
    draws = np.array([top_location(stack[k].sum(axis=0)) for k in picks])
    sd = np.maximum(draws.std(axis=0), 0.1)  # a tenth of a pixel: the top's resolution
    volume = volumes.sum(axis=0)
    turn = _turn_top(volume, turns)
    turn_sd = float(np.std([_turn_top(volumes[k].sum(axis=0), turns) for k in picks]))
    profile = volume.reshape(len(turns), -1).max(axis=1)
    gain = float(profile.max() / max(profile[n_turn], 1.0))
    turned = bool(abs(turn) >= min_turn_deg and gain >= MIN_TURN_GAIN)
    peaks = {i: top_location(per_object[i][n_turn]) for i in ids}
    axis = int(np.argmax(np.abs(shift)))
    agreement = sum(1 for p in peaks.values() if p[axis] * shift[axis] > 0
                    and abs(p[axis]) >= 0.5 * abs(shift[axis])) / len(ids)
    structured = bool(abs(shift[axis]) >= min_shift_px and agreement >= min_agreement) or turned
    return EdgeFinding(shift_px=(round(float(shift[0]), 3), round(float(shift[1]), 3)),
                       sd_px=(round(float(sd[0]), 3), round(float(sd[1]), 3)),
                       z=round(float(np.max(np.abs(shift) / sd)), 3),
                       agreement=round(agreement, 3), min_agreement=float(min_agreement),
                       min_shift_px=float(min_shift_px), structured=structured,
                       peaks_px={i: (round(p[0], 2), round(p[1], 2)) for i, p in peaks.items()},
                       correlation=total, turn_deg=round(turn, 3),
                       turn_sd_deg=round(max(turn_sd, 0.01), 3), turn_gain=round(gain, 3),
                       min_turn_deg=float(min_turn_deg), turn_structured=turned,
                       turn_profile=np.stack([turns, profile], axis=1))
