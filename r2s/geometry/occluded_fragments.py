"""A small mask id seen past an occluder from a larger one: a piece of the same object.

An object partly hidden by a nearer one is often seen in two pieces, one on each side of
the occluder; a segmenter may give the smaller piece an id of its own. The pieces share no
boundary in the image (the occluder lies between them), so
:mod:`r2s.geometry.mask_fragments`'s boundary test cannot join them. Reconstructed alone,
such a piece becomes a tiny object that topples or rolls in the simulation and ends far
from where it was seen.

A small id ``A`` is taken as part of a larger id ``B`` when

- it is small beside it: at most ``MAX_AREA_SHARE`` of ``B``'s pixels;
- the two do not touch in the image (two ids that touch are judged at their boundary);
- the straight image path between their nearest pixels (at most ``MAX_GAP_PX`` long)
  runs over other objects' masks only, never over unlabelled pixels (the table), and
  where those read a depth, it lies at least ``OCCLUSION_MARGIN_M`` nearer than the
  straight 3-D line from ``A``'s end to ``B``'s end: the space between the pieces is
  hidden from the camera, so one object may run on through it;
- the two ends are at most ``MAX_GAP_M`` apart in 3-D (ends back-projected at the median
  depth of their piece's pixels near the end);
- the colours of ``A`` are found on ``B``: the ``COLOUR_PERCENTILE`` percentile of the
  distance from each of ``A``'s pixel colours (its outline band left out: bleed) to the
  nearest colour of ``B`` is at most ``MAX_COLOUR_DISTANCE``.

Of several ``B`` that pass, the nearest in 3-D is taken. Pixel ``(row, col)``; depth along
the camera z axis in metres, NaN = no reading; ``K`` (3, 3) the pinhole intrinsics.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable, Optional

import numpy as np
from scipy import ndimage

from r2s.geometry.colour_sets import nearest_colour_distances

MAX_AREA_SHARE = 0.35
"""A piece seen past an occluder is small beside its object (a segmenter's sliver)."""
MAX_GAP_PX = 80.0
MAX_GAP_M = 0.12
"""The ends of the two pieces may be this far apart in 3-D (one object runs on hidden)."""
OCCLUSION_MARGIN_M = 0.005
MIN_HIDDEN_FRACTION = 0.9
"""Share of the path's valid depth readings (its first and last ``END_PX`` left out: depth
edges fly) that must lie in front of the line between the pieces."""
MIN_PATH_READINGS = 3
MIN_SHORT_PATH_READINGS = 2
"""A path too short for ``MIN_PATH_READINGS`` past its ends (``END_PX``) is read at every
occluder pixel on it, and needs this many readings: an occluder 2 px wide, the shaft of a
screwdriver 1.0-1.4 m from the camera between a cup and a strip of it."""
END_PX = 2
END_WINDOW_PX = 4
"""The depth of a piece's end: the median of its readings within this many pixels."""
BAND_PX = 2
"""A piece's outline band, left out of its colours (a mask bleeds there)."""
MAX_COLOUR_DISTANCE = 20.0
COLOUR_PERCENTILE = 75.0
COLOUR_SAMPLES = 400


@dataclass(frozen=True)
class Bridge:
    """Why ``small_id`` is taken as part of ``large_id``.

    occluder_ids : the ids the path between the pieces crosses.
    gap_px, gap_m : the path's length in the image and the ends' distance in 3-D.
    hidden_fraction : share of the path's valid readings in front of the line.
    colour_distance : the percentile distance of the small piece's colours to the large one's.
    """

    small_id: int
    large_id: int
    occluder_ids: tuple[int, ...]
    gap_px: float
    gap_m: float
    hidden_fraction: float
    colour_distance: float

    def describe(self) -> str:
        past = ", ".join(str(i) for i in self.occluder_ids)
        return (f"seen {1000 * self.gap_m:.0f} mm from it past instance {past}, which hides "
                f"the space between; colours {self.colour_distance:.0f} apart")


def _end_depth(own: np.ndarray, depth: np.ndarray, at: tuple[int, int]) -> float:
    """The median reading of ``own``'s pixels within ``END_WINDOW_PX`` of ``at``, else of
    all of them when none of those reads (NaN when nothing reads)."""
    win = _window(own.shape, at)
    z = depth[win][own[win]]
    z = z[np.isfinite(z) & (z > 0)]
    if not len(z):
        z = depth[own]
        z = z[np.isfinite(z) & (z > 0)]
    return float(np.median(z)) if len(z) else float("nan")


def _id_depth(masks: np.ndarray, depth: np.ndarray, at: tuple[int, int], oid: int) -> float:
    """The median reading of id ``oid``'s pixels within ``END_WINDOW_PX`` of ``at`` (depth
    edges read nothing or fly: the occluder's surface near the path, not the path's pixel
    alone); NaN when none reads."""
    win = _window(masks.shape, at)
    z = depth[win][masks[win] == oid]
    z = z[np.isfinite(z) & (z > 0)]
    return float(np.median(z)) if len(z) else float("nan")


def _window(shape: tuple[int, ...], at: tuple[int, int]) -> tuple[slice, slice]:
    r, c = at
    return (slice(max(r - END_WINDOW_PX, 0), min(r + END_WINDOW_PX + 1, shape[0])),
            slice(max(c - END_WINDOW_PX, 0), min(c + END_WINDOW_PX + 1, shape[1])))


def _ray(K: np.ndarray, at: tuple[int, int], z: float) -> np.ndarray:
    r, c = at
    return np.array([(c - K[0, 2]) / K[0, 0] * z, (r - K[1, 2]) / K[1, 1] * z, z])


def _colour_distance(small: np.ndarray, large: np.ndarray, rgb: np.ndarray) -> float:
    """``COLOUR_PERCENTILE`` percentile of the distances from each colour of ``small``
    (its outline band left out, unless that leaves fewer than 8 pixels) to the nearest
    colour of ``large`` (both (H, W) bool)."""
    inner = ndimage.binary_erosion(small, iterations=BAND_PX, border_value=0)
    to_large, _ = nearest_colour_distances(rgb[inner if int(inner.sum()) >= 8 else small],
                                           rgb[large], COLOUR_SAMPLES)
    return float(np.percentile(to_large, COLOUR_PERCENTILE))


def bridge(masks: np.ndarray, depth_m: np.ndarray, rgb: np.ndarray, K: np.ndarray,
           small_id: int, large_id: int) -> Optional[Bridge]:
    """The evidence that ``small_id`` is a piece of ``large_id`` seen past an occluder, or
    None when a test of the module docstring fails.

    masks : (H, W) int ids, 0 = none; depth_m : (H, W); rgb : (H, W, 3) uint8; K : (3, 3).
    """
    masks = np.asarray(masks)
    small, large = masks == small_id, masks == large_id
    if not small.any() or int(small.sum()) > MAX_AREA_SHARE * int(large.sum()):
        return None
    sr, sc = np.nonzero(small)
    lr, lc = np.nonzero(large)
    if max(lr.min() - sr.max(), sr.min() - lr.max(),
           lc.min() - sc.max(), sc.min() - lc.max()) > MAX_GAP_PX:
        return None
    # the nearest pixels, in the window of both (every pixel of either lies in it)
    r0, c0 = min(sr.min(), lr.min()), min(sc.min(), lc.min())
    win = (slice(r0, max(sr.max(), lr.max()) + 1), slice(c0, max(sc.max(), lc.max()) + 1))
    dist, (rows, cols) = ndimage.distance_transform_edt(~large[win], return_indices=True)
    k = int(np.argmin(dist[sr - r0, sc - c0]))
    gap_px = float(dist[sr[k] - r0, sc[k] - c0])
    if gap_px <= 1.5 or gap_px > MAX_GAP_PX:
        return None
    a = (int(sr[k]), int(sc[k]))
    b = (int(rows[a[0] - r0, a[1] - c0]) + r0, int(cols[a[0] - r0, a[1] - c0]) + c0)
    depth = np.asarray(depth_m, dtype=np.float64)
    za, zb = _end_depth(small, depth, a), _end_depth(large, depth, b)
    if not (np.isfinite(za) and np.isfinite(zb)):
        return None
    n = int(np.ceil(gap_px)) + 1
    t = np.linspace(0.0, 1.0, n)
    pr = np.rint(a[0] + t * (b[0] - a[0])).astype(int)
    pc = np.rint(a[1] + t * (b[1] - a[1])).astype(int)
    ids = masks[pr, pc]
    between = (ids != small_id) & (ids != large_id)
    if not between.any() or np.any(ids[between] == 0):
        return None
    # the line's depth along the path: linear in inverse depth (a 3-D line in the image)
    line = 1.0 / ((1.0 - t) / za + t / zb)
    along = t * gap_px
    inner = between & (along > END_PX) & (along < gap_px - END_PX)
    needed = MIN_PATH_READINGS
    if int(inner.sum()) < MIN_PATH_READINGS:
        # a thin occluder (a far camera's few pixels): every pixel of it on the path; its
        # readings are its own surface's near the path (_id_depth), not the edge pixel's
        inner, needed = between, MIN_SHORT_PATH_READINGS
    z = np.array([_id_depth(masks, depth, (r, c), int(i)) if ok else np.nan
                  for r, c, i, ok in zip(pr, pc, ids, inner)])
    valid = np.isfinite(z)
    if int(valid.sum()) < needed:
        return None
    hidden = float(np.mean(z[valid] < line[valid] - OCCLUSION_MARGIN_M))
    if hidden < MIN_HIDDEN_FRACTION:
        return None
    Kf = np.asarray(K, dtype=np.float64)
    gap_m = float(np.linalg.norm(_ray(Kf, a, za) - _ray(Kf, b, zb)))
    if gap_m > MAX_GAP_M:
        return None
    colour = _colour_distance(small, large, np.asarray(rgb)[..., :3])
    if colour > MAX_COLOUR_DISTANCE:
        return None
    return Bridge(int(small_id), int(large_id), tuple(sorted(set(ids[between].tolist()))),
                  gap_px, gap_m, hidden, colour)


def occluded_parents(masks: np.ndarray, depth_m: np.ndarray, rgb: np.ndarray, K: np.ndarray,
                     protected_ids: Iterable[int] = (),
                     distinct: Optional[Callable[[int, int], bool]] = None
                     ) -> dict[int, tuple[int, str]]:
    """``{piece id: (the id of the whole object it is part of, why)}`` for the pieces of
    the module docstring. ``protected_ids`` (ids with a shape prior: whole objects) are never
    pieces, nor is an id joined to one that ``distinct(a, b)`` says is another object. Ids
    are tried smallest first, each against every id at least 1 / ``MAX_AREA_SHARE`` times
    its size (so none of those is a piece yet)."""
    masks = np.asarray(masks)
    protected = {int(i) for i in protected_ids}
    ids = [int(i) for i in np.unique(masks) if i > 0]
    sizes = {i: int((masks == i).sum()) for i in ids}
    out: dict[int, tuple[int, str]] = {}
    for small in sorted(ids, key=sizes.get):
        if small in protected:
            continue
        found = [bridge(masks, depth_m, rgb, K, small, large) for large in ids
                 if sizes[small] <= MAX_AREA_SHARE * sizes[large]
                 and not (distinct is not None and distinct(small, large))]
        found = [f for f in found if f is not None]
        if found:
            best = min(found, key=lambda f: f.gap_m)
            out[small] = (best.large_id, best.describe())
    for piece in list(out):  # a piece of a piece: to the root (sizes grow along a chain)
        root, why = out[piece]
        while root in out:
            root = out[root][0]
        out[piece] = (root, why)
    return out
