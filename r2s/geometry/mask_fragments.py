"""Mask ids that are pieces of one object: a segmenter's splits and slivers.

A segmentation network sometimes cuts one object in two (a split along a line through it)
or gives a strip of an object, seen beside or behind a nearer one, an id of its own (a
sliver). Reconstructed as separate objects, the two pieces overlap where each is
completed into the other's space, and the simulation pushes them apart or topples the
smaller one. Two ids are taken for one object when, along the boundary they share in the
image,

- the depth is continuous: at least ``min_continuous_fraction`` of the 4-neighbour pixel
  pairs across it (both readings valid) differ by less than ``max(jump_min_m,
  jump_fraction * z)``: the same surface runs on across the cut; two objects that touch
  in the image are mostly at different depths there (one in front of the other);
- the colour is continuous (for a sliver, :meth:`BoundaryEvidence.is_sliver`, within the
  looser bound alone): the two sides' strips along the boundary (``strip_px`` deep,
  starting ``BLEED_PX`` in: a mask that bleeds onto its neighbour carries the neighbour's
  colour and depth in its first pixels) hold the same colours: the distance from a pixel
  colour of either strip to the nearest pixel colour of the other (75th percentile) is at most
  ``MAX_COLOUR_SET_DISTANCE`` (RGB, 0-255, Euclidean; this holds for a textured object, a
  football or a printed box, whose two pieces' mean colours differ by where the cut runs
  through the print), or their mean colours are at most ``MAX_COLOUR_DISTANCE`` apart
  and that distance is at most ``MAX_COLOUR_SET_DISTANCE_WITH_MEANS``;
- the boundary is long enough to judge (``min_pairs`` valid pairs) and is a real part of
  the smaller piece's outline (``min_outline_fraction``).

The smaller id is the fragment and goes to the larger one, except that an id the user
declared (an objects.json entry: a label, a mass) is kept over an undeclared one (a
segmenter's new id); an id with a shape prior is never a fragment (a prior describes a
whole object), and two ids with priors are never merged. Chains (a fragment of a fragment) resolve to the root.

Pixel ``(row, col)``; depth along the camera z axis in metres, NaN = no reading.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable, Mapping, Optional

import numpy as np
from scipy import ndimage

from r2s.geometry.colour_sets import nearest_colour_distances
from r2s.geometry.occluded_fragments import occluded_parents

JUMP_MIN_M = 0.006
JUMP_FRACTION = 0.01
MIN_CONTINUOUS_FRACTION = 0.85
MAX_COLOUR_DISTANCE = 40.0
MAX_COLOUR_SET_DISTANCE = 8.0
"""RGB units: two strips whose colours match this well are one surface whatever their means."""
MAX_COLOUR_SET_DISTANCE_WITH_MEANS = 40.0
"""RGB units: close means are not enough when one strip holds colours far from all of the
other's (a black-and-white football beside a grey box averages to the box's grey).
Calibration (synthetic RealSense-like scenes, seeds 200-239, 300-319 and 400-419 with 5-8
objects, and the 10 realistic benchmark scenes; ``scripts/check_mask_fragments.py``):
split pieces whose means are more than 40 apart had a nearest-colour distance (75th
percentile) of 2.0-7.5 in 10 of 18 cases, 9.1-43 in the others; split pieces with means
within 40, at most 27.6; pairs of different objects with a continuous depth boundary,
11.4 or more (120.9 for the football and the box). One such pair, a padlock beside a
pudding box (means 17.5 apart, nearest 11.4), is still taken for one object."""
COLOUR_SET_PERCENTILE = 75.0
"""The nearest-colour distance is this percentile over both strips' pixels: most of
either side's colours must be found on the other (a median let a black drill and a
black-and-white football pass on their shared black)."""
COLOUR_SET_SAMPLES = 400
"""At most this many strip pixels per side (every k-th) enter the nearest-colour test:
the distance shrinks as samples grow, so both sides are capped alike."""
SLIVER_MAX_PX = 300
SLIVER_MAX_SHARE = 0.15
SLIVER_MIN_PAIRS = 10
SLIVER_MIN_CONTINUOUS_FRACTION = 0.90
"""A sliver (a strip of an object along a nearer one, a few pixels wide: its pixels are
the edge's mixed colours, its strip is all of it) joins across a boundary of continuous
depth with colours within ``MAX_COLOUR_SET_DISTANCE_WITH_MEANS``, whatever the means.
On 70 synthetic scenes (seeds 600-669) and the 10 realistic benchmark scenes, the ids of
at most 300 px whose boundary with a larger one is >= 90 % continuous over >= 10 pairs
and that the rule before did not join: 8 pairs, all pieces of one object (colour set
distances 13.8-39.9 in 6, 73.5 and 192.8 in 2); no pair of different objects. The bound
was 95 % until a camera 1.0-1.4 m away (depth noise about 4 mm) left a screwdriver's 59 px
strip apart at 91 % (docs/realistic.md, "A far camera")."""
MIN_STRIP_PX = 8
"""A strip with fewer pixels past the bleed band is taken whole (bleed band included)."""
DEPTH_FILL_PX = 3
"""Where fewer than ``MIN_VALID_PAIRS`` pixel pairs across a boundary have readings on both
sides, a pixel without one takes the nearest reading of its own id within this many pixels
(``_filled_depth``): on dark or shiny objects the sensor reads a fifth of the pixels or
fewer, and a split through such an object (a jenga block of the piles set, 21 and 31 %
valid on its two pieces) left 2 of 63 boundary pairs, too few to judge. Only then: filled
on every boundary, one split that 5 raw pairs join (continuous 1.0) read 0.84 continuous
over 31 filled pairs, under the bar (realistic scene_04's mustard bottle)."""
MIN_PAIRS = 8
MIN_VALID_PAIRS = 4
MIN_OUTLINE_FRACTION = 0.05
STRIP_PX = 4
BLEED_PX = 4
MERGE_ROUNDS = 3
"""Rounds of the boundary test, each on the masks with the pieces found so far merged."""


@dataclass(frozen=True)
class BoundaryEvidence:
    """What the shared boundary of two mask ids says.

    pairs : 4-neighbour pixel pairs across the boundary with valid depth on both sides
        (where fewer than ``MIN_VALID_PAIRS`` have it, a missing reading is taken from its
        side's nearest within ``DEPTH_FILL_PX``).
    continuous_fraction : share of those pairs without a depth jump.
    boundary_pairs : all 4-neighbour pixel pairs across the boundary (a thin object's split
        is short, and depth is often missing along it).
    colour_distance : RGB distance of the two sides' mean colours along the boundary.
    colour_set_distance : RGB distance from a strip pixel's colour to the nearest colour
        of the other side's strip, both ways, its ``COLOUR_SET_PERCENTILE`` percentile.
    outline_fraction : boundary pixels of the smaller id over its outline pixels.
    """

    small_id: int
    large_id: int
    pairs: int
    continuous_fraction: float
    colour_distance: float
    outline_fraction: float
    boundary_pairs: int
    colour_set_distance: float
    small_px: int = 0
    large_px: int = 0

    def is_sliver(self) -> bool:
        """A strip of an object along an occluder (``small_px`` at most ``SLIVER_MAX_PX``
        and ``SLIVER_MAX_SHARE`` of the other) on a boundary of continuous depth."""
        return (0 < self.small_px <= SLIVER_MAX_PX
                and self.small_px <= SLIVER_MAX_SHARE * self.large_px
                and self.pairs >= SLIVER_MIN_PAIRS
                and self.continuous_fraction >= SLIVER_MIN_CONTINUOUS_FRACTION)

    def colours_continue(self) -> bool:
        if self.is_sliver():
            return self.colour_set_distance <= MAX_COLOUR_SET_DISTANCE_WITH_MEANS
        return (self.colour_set_distance <= MAX_COLOUR_SET_DISTANCE
                or (self.colour_distance <= MAX_COLOUR_DISTANCE
                    and self.colour_set_distance <= MAX_COLOUR_SET_DISTANCE_WITH_MEANS))

    def is_one_object(self) -> bool:
        return (self.pairs >= MIN_VALID_PAIRS and self.boundary_pairs >= MIN_PAIRS
                and self.continuous_fraction >= MIN_CONTINUOUS_FRACTION
                and self.colours_continue()
                and self.outline_fraction >= MIN_OUTLINE_FRACTION)

    def describe(self) -> str:
        colours = (f"colours {self.colour_distance:.0f} apart"
                   if self.colour_distance <= MAX_COLOUR_DISTANCE else
                   f"the same colours (nearest {self.colour_set_distance:.0f} apart)")
        return (f"depth continuous over {100 * self.continuous_fraction:.0f} % of "
                f"{self.pairs} boundary pixel pairs, {colours}")


def _pairs(masks: np.ndarray) -> Iterable[tuple[np.ndarray, np.ndarray]]:
    """(a, b) flat index arrays of horizontally and vertically adjacent pixels."""
    h, w = masks.shape
    idx = np.arange(h * w).reshape(h, w)
    yield idx[:, :-1].ravel(), idx[:, 1:].ravel()
    yield idx[:-1, :].ravel(), idx[1:, :].ravel()


def boundary_evidence(masks: np.ndarray, depth_m: np.ndarray, rgb: np.ndarray,
                      jump_min_m: float = JUMP_MIN_M, jump_fraction: float = JUMP_FRACTION,
                      strip_px: int = STRIP_PX) -> list[BoundaryEvidence]:
    """The evidence of every pair of ids that share a boundary.

    masks : (H, W) int ids, 0 = none; depth_m : (H, W); rgb : (H, W, 3) uint8.
    """
    m = np.asarray(masks).ravel()
    z_raw = np.asarray(depth_m, dtype=np.float64)
    z = z_raw.ravel()
    z_filled = None
    a_all, b_all = (np.concatenate(x) for x in zip(*_pairs(np.asarray(masks))))
    cross = (m[a_all] != m[b_all]) & (m[a_all] > 0) & (m[b_all] > 0)
    a_all, b_all = a_all[cross], b_all[cross]
    if not len(a_all):
        return []
    lo, hi = np.minimum(m[a_all], m[b_all]), np.maximum(m[a_all], m[b_all])
    sizes = np.bincount(m)
    out = []
    for i, j in sorted(set(zip(lo.tolist(), hi.tolist()))):
        sel = (lo == i) & (hi == j)
        za, zb = z[a_all[sel]], z[b_all[sel]]
        valid = np.isfinite(za) & np.isfinite(zb) & (za > 0) & (zb > 0)
        if valid.sum() < MIN_VALID_PAIRS:
            if z_filled is None:
                z_filled = _filled_depth(np.asarray(masks), z_raw).ravel()
            za, zb = z_filled[a_all[sel]], z_filled[b_all[sel]]
            valid = np.isfinite(za) & np.isfinite(zb) & (za > 0) & (zb > 0)
        n_valid = int(valid.sum())
        jump = np.maximum(jump_min_m, jump_fraction * np.minimum(za[valid], zb[valid]))
        continuous = float(np.mean(np.abs(za[valid] - zb[valid]) < jump)) if n_valid else 0.0
        small, large = (i, j) if sizes[i] <= sizes[j] else (j, i)
        window = _pair_window(np.asarray(masks), i, j)
        crop_masks, crop_rgb = np.asarray(masks)[window], np.asarray(rgb)[window]
        mean_dist, set_dist = _colour_distances(crop_masks, crop_rgb, i, j, strip_px)
        out.append(BoundaryEvidence(
            small_id=int(small), large_id=int(large), pairs=n_valid,
            continuous_fraction=continuous, colour_distance=mean_dist,
            outline_fraction=_outline_fraction(crop_masks, small, large),
            boundary_pairs=int(sel.sum()), colour_set_distance=set_dist,
            small_px=int(sizes[small]), large_px=int(sizes[large])))
    return out


def _filled_depth(masks: np.ndarray, depth_m: np.ndarray, radius_px: int = DEPTH_FILL_PX
                  ) -> np.ndarray:
    """(H, W) ``depth_m`` with each masked pixel that has no reading (NaN or <= 0) given the
    reading of the nearest pixel of the same id that has one, within ``radius_px``
    (Euclidean); other pixels keep theirs (NaN where none is near)."""
    out = depth_m.copy()
    valid = np.isfinite(depth_m) & (depth_m > 0)
    for obj_id in np.unique(masks[(masks > 0) & ~valid]):
        window = _pair_window(masks, int(obj_id), int(obj_id))
        own = masks[window] == obj_id
        own_valid = own & valid[window]
        if not own_valid.any():
            continue
        dist, (rows, cols) = ndimage.distance_transform_edt(~own_valid, return_indices=True)
        fill = own & ~valid[window] & (dist <= radius_px)
        crop = out[window]
        crop[fill] = depth_m[window][rows[fill], cols[fill]]
    return out


def _pair_window(masks: np.ndarray, i: int, j: int) -> tuple[slice, slice]:
    """The bounding box of ids ``i`` and ``j`` grown by one pixel (clipped to the image):
    every pixel of both lies in it, so distances to either and their outlines are the
    same as on the whole image."""
    rows, cols = np.nonzero((masks == i) | (masks == j))
    h, w = masks.shape
    return (slice(max(int(rows.min()) - 1, 0), min(int(rows.max()) + 2, h)),
            slice(max(int(cols.min()) - 1, 0), min(int(cols.max()) + 2, w)))


def _colour_distances(masks: np.ndarray, rgb: np.ndarray, i: int, j: int, strip_px: int,
                      skip_px: int = BLEED_PX) -> tuple[float, float]:
    """(RGB distance of the mean colours, :func:`_colour_set_distance`) of each id's pixels
    between ``skip_px`` and ``skip_px + strip_px`` from the other (the first pixels
    may be the other's, by bleed); (inf, inf) when a side has no pixels."""
    mi, mj = masks == i, masks == j
    dist_to_j = ndimage.distance_transform_edt(~mj)
    dist_to_i = ndimage.distance_transform_edt(~mi)
    side_i = _strip(mi, dist_to_j, skip_px, strip_px)
    side_j = _strip(mj, dist_to_i, skip_px, strip_px)
    if not side_i.any() or not side_j.any():
        return float("inf"), float("inf")
    col = np.asarray(rgb, dtype=np.float64)[..., :3]
    a, b = col[side_i], col[side_j]
    return float(np.linalg.norm(a.mean(axis=0) - b.mean(axis=0))), _colour_set_distance(a, b)


def _colour_set_distance(a: np.ndarray, b: np.ndarray) -> float:
    """``COLOUR_SET_PERCENTILE`` percentile of the distances from each of (N, 3) colours
    ``a`` to the nearest of (M, 3) ``b`` and back; each side thinned to at most
    ``COLOUR_SET_SAMPLES`` (every k-th)."""
    a_to_b, b_to_a = nearest_colour_distances(a, b, COLOUR_SET_SAMPLES)
    return float(np.percentile(np.concatenate([a_to_b, b_to_a]), COLOUR_SET_PERCENTILE))


def _strip(own: np.ndarray, dist_to_other: np.ndarray, skip_px: int, strip_px: int
           ) -> np.ndarray:
    """(H, W) bool: ``own`` pixels between ``skip_px`` and ``skip_px + strip_px`` from the
    other id; all those within ``skip_px + strip_px`` when fewer than ``MIN_STRIP_PX`` lie
    past the bleed band (a sliver or a thin split: nearly every pixel of it is its own)."""
    near = own & (dist_to_other <= skip_px + strip_px)
    inner = near & (dist_to_other > skip_px)
    return inner if int(inner.sum()) >= MIN_STRIP_PX else near


def _outline_fraction(masks: np.ndarray, small: int, large: int) -> float:
    """Outline pixels of ``small`` that touch ``large`` (4-neighbourhood), over all its
    outline pixels."""
    ms = masks == small
    outline = ms & ~ndimage.binary_erosion(ms, border_value=0)
    touching = outline & ndimage.binary_dilation(masks == large)
    return float(touching.sum()) / max(int(outline.sum()), 1)


def fragment_parents(masks: np.ndarray, depth_m: np.ndarray, rgb: np.ndarray,
                     protected_ids: Iterable[int] = (), declared_ids: Iterable[int] = (),
                     K: Optional[np.ndarray] = None,
                     labels: Optional[Mapping[int, str]] = None) -> dict[int, tuple[int, str]]:
    """``{fragment id: (the id of the object it is part of, why)}`` (see the module
    docstring). ``protected_ids``: ids that are whole objects (they have a shape prior);
    ``declared_ids``: ids the user named (kept over undeclared ones when merged). With the
    camera's ``K`` (3, 3), ids left whole by the boundary test are then tested for pieces
    seen past an occluder (:mod:`r2s.geometry.occluded_fragments`). ``labels``: the labels
    the user gave ids; two ids with different labels are two objects and never joined.

    The boundary test runs again on the masks with the pieces found merged, up to
    ``MERGE_ROUNDS`` times: a sliver lying along the cut between two halves of a split
    object takes most of the boundary they share, and only once the sliver has joined one
    half does the other half's boundary with it become long enough to judge."""
    protected = set(int(i) for i in protected_ids)
    declared = set(int(i) for i in declared_ids) | protected
    named = {int(i): str(v) for i, v in (labels or {}).items()}

    def distinct(a: int, b: int) -> bool:
        return a in named and b in named and named[a] != named[b]

    resolved: dict[int, tuple[int, str]] = {}
    for _ in range(MERGE_ROUNDS):
        found = _boundary_parents(merge_masks(masks, resolved), depth_m, rgb, protected,
                                  declared, distinct)
        if not found:
            break
        resolved = _composed(resolved, found)
    if K is None:
        return resolved
    bridged = occluded_parents(merge_masks(masks, resolved), depth_m, rgb, K, protected,
                               distinct)
    resolved.update(bridged)
    for piece, (root, why) in bridged.items():
        if piece in declared and root not in declared and root not in resolved:
            # the declared id names the object (once): the root and its other pieces go to it
            resolved = {f: (piece if p == root else p, w)
                        for f, (p, w) in resolved.items() if f != piece}
            resolved[root] = (piece, why)
    return resolved


def _boundary_parents(masks: np.ndarray, depth_m: np.ndarray, rgb: np.ndarray,
                      protected: set[int], declared: set[int],
                      distinct: Callable[[int, int], bool]) -> dict[int, tuple[int, str]]:
    """One round of the boundary test: ``{fragment id: (root id, why)}``, chains resolved;
    no pair that ``distinct`` says are two objects."""
    parent: dict[int, tuple[int, str]] = {}
    evidence = sorted(boundary_evidence(masks, depth_m, rgb), key=lambda e: -e.pairs)
    for ev in evidence:
        if not ev.is_one_object() or distinct(ev.small_id, ev.large_id):
            continue
        small, large = ev.small_id, ev.large_id
        if small in protected:
            if large in protected:
                continue
            small, large = large, small
        elif small in declared and large not in declared:
            small, large = large, small
        if small in parent:
            continue
        parent[small] = (large, ev.describe())
    # resolve chains; a cycle cannot form (each id has one parent, chosen once) except
    # through a swap above: break it by dropping the later link
    resolved: dict[int, tuple[int, str]] = {}
    for frag, (par, why) in parent.items():
        seen = {frag}
        while par in parent and par not in seen:
            seen.add(par)
            par = parent[par][0]
        if par != frag:
            resolved[frag] = (par, why)
    return resolved


def _composed(first: dict[int, tuple[int, str]], then: dict[int, tuple[int, str]]
              ) -> dict[int, tuple[int, str]]:
    """The merges of ``first`` followed by those found on its merged masks (``then``,
    whose fragments are roots of ``first``): every id to its final root."""
    out = {frag: (then[root][0] if root in then else root, why)
           for frag, (root, why) in first.items()}
    out.update(then)
    return out


def merge_masks(masks: np.ndarray, parents: dict[int, tuple[int, str]]) -> np.ndarray:
    """(H, W) ``masks`` with every fragment id replaced by its parent's."""
    out = np.asarray(masks).copy()
    for frag, (par, _) in parents.items():
        out[out == frag] = par
    return out
