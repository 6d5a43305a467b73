"""Which of an instance mask's depth pixels are really the object's, before completing it.

A segmenter's mask holds pixels that are not the object's: it bleeds onto the table, onto
a neighbour in front of or behind the object, and mixed ("flying") depth readings sit at
its depth edges. Completion turns every kept point into material, so a few foreign points
stretch the footprint far past the object. Two tests, on the mask's pixels:

- *support band*: points within ``plane_band_m`` of the support plane, on the mask's outer
  ``edge_px`` ring where it borders no other object's mask, are the table (bleed reaches
  into a mask from its outline; the object's own base is restored by the extrusion down to
  the support), and so are the band's points deeper inside that are joined to those
  through band points (a bleed wider than the ring, such as a shadow a segmenter took into
  the mask); skipped when too few points would remain (a flat object lying on the
  table). Band points deeper inside and cut off from the outline by the object are kept:
  table seen *through* an object's mask is cut off from the table around it, while the
  floor of a plate or a tray, a few millimetres up, is the object's own surface (dropping
  it carved the plate into a ring);
- *surface continuity*: mask pixels are linked to their 8 image neighbours when their
  depths differ by less than ``max(jump_min_m, jump_fraction * z)`` (a surface seen even
  at a grazing angle changes depth smoothly from pixel to pixel; bleed onto something
  nearer or farther sits across a depth jump). Linked regions smaller than
  ``min_region_fraction`` of the largest in the same part of the mask are dropped (the
  largest region and any region nearly as large are kept); a part of the mask cut off
  from the rest by an occluder (a plate's far rim seen between an apple and a banana) is
  compared only with itself, since bleed grows into a mask from its outline;
- *bleed onto a neighbour* (given the neighbours' depths): a linked region other than
  the largest of its part, all of whose pixels lie within ``bleed_band_px`` of another
  object's mask and at least half of which read that neighbour's depth there (within the
  same jump), is the neighbour's surface and is dropped however large it is against the
  object's own: a small object seen past a nearer one, noisy and cut into pieces by
  holes, is otherwise outweighed by the strip of the occluder its mask took in.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from r2s.geometry.plane import signed_distance

PLANE_BAND_M = 0.006
EDGE_PX = 6
JUMP_MIN_M = 0.008
JUMP_FRACTION = 0.015
MIN_REGION_FRACTION = 0.25
MIN_KEEP_FRACTION = 0.3
BLEED_BAND_PX = 6
"""Bleed onto a neighbour reaches at most this far from the neighbour's mask (pixels; the
widest bleed of the realistic benchmark's segmenter model is 4 px)."""
NEIGHBOUR_SAMPLES = 5
"""A pixel is compared with the median depth of this many nearest neighbour pixels."""


def interior_pixels(pixels: np.ndarray, edge_px: int,
                    neighbours: np.ndarray | None = None) -> np.ndarray:
    """(N,) bool: which of the mask pixels ``pixels`` ((N, 2) int (row, col), distinct) lie
    more than ``edge_px`` pixels (Euclidean) inside the mask's outline. Holes in the pixel
    set (no depth reading) are filled first, so a hole does not make an outline; where
    ``neighbours`` ((M, 2) pixels of the other objects' masks) border the mask there is no
    outline either (bleed onto the table comes in from where the table is seen)."""
    pix = np.asarray(pixels, dtype=np.int64).reshape(-1, 2)
    if len(pix) == 0:
        return np.zeros(0, dtype=bool)
    pad = min(int(edge_px), 32) + 1  # neighbours this close to the mask count
    rr, cc, shape = _window(pix, pad)
    mask = np.zeros(shape, dtype=bool)
    mask[rr, cc] = True
    solid = ndimage.binary_fill_holes(mask)
    if neighbours is not None and len(neighbours):
        other = np.asarray(neighbours, dtype=np.int64).reshape(-1, 2)
        other = other - pix.min(axis=0) + pad  # into the window
        ok = np.all((other >= 0) & (other < shape), axis=1)
        solid[other[ok, 0], other[ok, 1]] = True
    inside = ndimage.distance_transform_edt(solid)
    return inside[rr, cc] > edge_px


def _window(pix: np.ndarray, pad: int = 1) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """Rows and columns of the (N, 2) pixels in their bounding box grown by ``pad`` pixels
    on every side, and that window's shape."""
    r0, c0 = pix.min(axis=0)
    h, w = pix.max(axis=0) - (r0, c0) + 1
    return pix[:, 0] - r0 + pad, pix[:, 1] - c0 + pad, (int(h) + 2 * pad, int(w) + 2 * pad)


def _reached_from(seeds: np.ndarray, passable: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """(N,) bool: the ``passable`` pixels (N,) bool of the mask's (N, 2) ``pixels`` that are
    8-connected to a ``seeds`` pixel through passable ones: the table that a wide bleed (a
    shadow taken into the mask) carries in from the outline, past the outer ring."""
    pix = np.asarray(pixels, dtype=np.int64).reshape(-1, 2)
    out = np.zeros(len(pix), dtype=bool)
    if not np.any(seeds & passable):
        return out
    rr, cc, shape = _window(pix)
    grid = np.zeros(shape, dtype=bool)
    grid[rr[passable], cc[passable]] = True
    labels, _ = ndimage.label(grid, np.ones((3, 3), dtype=bool))
    hit = np.unique(labels[rr[seeds & passable], cc[seeds & passable]])
    hit = hit[hit > 0]
    out[passable] = np.isin(labels[rr[passable], cc[passable]], hit)
    return out


PART_GAP_PX = 2
"""Mask pixels closer than twice this (a depth hole, a thin occluder) are one part."""


MIN_PART_PX = 100
"""A part of the mask with fewer pixels is compared with the whole mask's largest region
(a speck cut off from the rest is more likely noise than the object seen past an
occluder)."""


def mask_parts(pixels: np.ndarray, gap_px: int = PART_GAP_PX) -> np.ndarray:
    """(N,) int part label of each of the (N, 2) mask pixels: the connected parts of the
    mask once gaps narrower than ``2 * gap_px`` pixels are closed."""
    pix = np.asarray(pixels, dtype=np.int64).reshape(-1, 2)
    if len(pix) == 0:
        return np.zeros(0, dtype=np.int64)
    rr, cc, shape = _window(pix, gap_px + 1)
    mask = np.zeros(shape, dtype=bool)
    mask[rr, cc] = True
    grown = ndimage.binary_dilation(mask, iterations=gap_px) if gap_px > 0 else mask
    labels, _ = ndimage.label(grown, np.ones((3, 3), dtype=bool))
    return labels[rr, cc].astype(np.int64) - 1


def same_surface(z_a: np.ndarray, z_b: np.ndarray, jump_min_m: float = JUMP_MIN_M,
                 jump_fraction: float = JUMP_FRACTION) -> np.ndarray:
    """Elementwise bool: depths ``z_a`` and ``z_b`` (metres) differ by less than the jump
    ``max(jump_min_m, jump_fraction * min(z_a, z_b))`` that separates two surfaces."""
    return np.abs(z_a - z_b) < np.maximum(jump_min_m, jump_fraction * np.minimum(z_a, z_b))


def surface_regions(pixels: np.ndarray, depth_m: np.ndarray, jump_min_m: float = JUMP_MIN_M,
                    jump_fraction: float = JUMP_FRACTION) -> np.ndarray:
    """(N,) int region label of each pixel: 8-connected pixels without a depth jump.

    pixels : (N, 2) int ``(row, col)``, distinct; depth_m : (N,) their depths (metres).
    """
    pix = np.asarray(pixels, dtype=np.int64).reshape(-1, 2)
    z = np.asarray(depth_m, dtype=np.float64).reshape(-1)
    n = len(pix)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    rr, cc, shape = _window(pix)
    index = np.full(shape, -1, dtype=np.int64)
    index[rr, cc] = np.arange(n)
    src, dst = [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        other = index[rr + dr, cc + dc]
        ok = other >= 0
        a, b = np.flatnonzero(ok), other[ok]
        near = same_surface(z[a], z[b], jump_min_m, jump_fraction)
        src.append(a[near])
        dst.append(b[near])
    src, dst = np.concatenate(src), np.concatenate(dst)
    graph = sparse.coo_matrix((np.ones(len(src), dtype=np.int8), (src, dst)), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    return labels.astype(np.int64)


def part_labels(pixels: np.ndarray, mask_pixels: np.ndarray | None
                ) -> tuple[np.ndarray, np.ndarray]:
    """(N,) part label (0..P-1) of each of the (N, 2) ``pixels`` (:func:`mask_parts`) and
    (P,) each part's size in pixels.

    With ``mask_pixels`` ((M, 2), the whole instance mask, pixels without a depth reading
    too) the parts are the mask's and their sizes count every mask pixel: a thin part seen
    past an occluder reads depth in few of its pixels and is no speck for that (pixels
    outside the mask make parts of their own, sized by their count). Without it, the parts
    of ``pixels`` themselves."""
    pix = np.asarray(pixels, dtype=np.int64).reshape(-1, 2)
    if mask_pixels is None or len(mask_pixels) == 0 or len(pix) == 0:
        part = mask_parts(pix)
        return part, np.bincount(part)
    whole = np.asarray(mask_pixels, dtype=np.int64).reshape(-1, 2)
    whole_part = mask_parts(whole)
    r0, c0 = whole.min(axis=0)
    shape = tuple(whole.max(axis=0) - (r0, c0) + 1)
    lookup = np.full(shape, -1, dtype=np.int64)
    lookup[whole[:, 0] - r0, whole[:, 1] - c0] = whole_part
    rr, cc = pix[:, 0] - r0, pix[:, 1] - c0
    inside = (rr >= 0) & (cc >= 0) & (rr < shape[0]) & (cc < shape[1])
    part = np.full(len(pix), -1, dtype=np.int64)
    part[inside] = lookup[rr[inside], cc[inside]]
    stray = part < 0
    if stray.any():
        part[stray] = whole_part.max() + 1 + mask_parts(pix[stray])
    sizes = np.bincount(np.concatenate([whole_part, part[stray]]))
    used, part = np.unique(part, return_inverse=True)
    return part.astype(np.int64), sizes[used]


def object_point_mask(points_world: np.ndarray, pixels: np.ndarray, depth_m: np.ndarray,
                      plane_point: np.ndarray, plane_normal: np.ndarray,
                      plane_band_m: float = PLANE_BAND_M,
                      min_region_fraction: float = MIN_REGION_FRACTION,
                      min_keep_fraction: float = MIN_KEEP_FRACTION,
                      edge_px: int = EDGE_PX, neighbour_pixels: np.ndarray | None = None,
                      mask_pixels: np.ndarray | None = None,
                      neighbour_depth_m: np.ndarray | None = None) -> np.ndarray:
    """(N,) bool: which of an instance's observed points belong to the object.

    points_world : (N, 3) back-projected mask pixels; pixels : (N, 2) their (row, col);
    depth_m : (N,) their observed depths; plane_point, plane_normal : the support plane
    (normal up); neighbour_pixels : (M, 2) the other objects' mask pixels (the support
    band's ring runs only where the mask borders no other object); mask_pixels : (K, 2)
    the whole instance mask, pixels without depth too (the mask's parts are then sized by
    their mask pixels, :func:`part_labels`; None: by their readings);
    neighbour_depth_m : (M,) the depth at ``neighbour_pixels`` (NaN: no reading), for the
    bleed-onto-a-neighbour test (None: no such test). At least
    ``min_keep_fraction`` of the points (and 10) are always kept: when a test would drop
    more it is skipped.
    """
    pts = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    n = len(pts)
    keep = np.all(np.isfinite(pts), axis=1)
    floor = max(10, int(np.ceil(min_keep_fraction * n)))
    if n == 0:
        return keep
    above = signed_distance(pts, plane_point, plane_normal) > plane_band_m
    inner = interior_pixels(pixels, edge_px, neighbour_pixels)
    above |= inner & ~_reached_from(~above & ~inner, ~above, pixels)
    if np.count_nonzero(keep & above) >= floor:
        keep &= above
    idx = np.flatnonzero(keep)
    labels = surface_regions(np.asarray(pixels)[idx], np.asarray(depth_m)[idx])
    sizes = np.bincount(labels)
    # compared within each part of the mask: a part cut off by an occluder is the object
    # seen past it, not bleed (bleed grows into a mask from its outline)
    part, part_px = part_labels(np.asarray(pixels)[idx], mask_pixels)
    largest = np.zeros(part.max() + 1, dtype=np.int64)
    np.maximum.at(largest, part, sizes[labels])
    small_part = part_px < MIN_PART_PX  # specks are judged against the whole mask
    largest[small_part] = sizes.max()
    region_keep = sizes[labels] >= min_region_fraction * largest[part]
    if neighbour_pixels is not None and neighbour_depth_m is not None:
        on_neighbour = _on_neighbour(np.asarray(pixels)[idx], np.asarray(depth_m)[idx],
                                     labels, neighbour_pixels, neighbour_depth_m)
        is_largest = sizes[labels] == largest[part]
        region_keep &= ~(on_neighbour[labels] & ~is_largest)
    if np.count_nonzero(region_keep) >= floor:
        keep[idx[~region_keep]] = False
    return keep


def _on_neighbour(pixels: np.ndarray, depth_m: np.ndarray, labels: np.ndarray,
                  neighbour_pixels: np.ndarray, neighbour_depth_m: np.ndarray,
                  band_px: float = BLEED_BAND_PX) -> np.ndarray:
    """(R,) bool per region label: every pixel within ``band_px`` of a neighbour's mask,
    and at least half of them at the depth the neighbour reads nearby (the median of its
    ``NEIGHBOUR_SAMPLES`` nearest pixels with a reading, within the surface jump)."""
    n_regions = int(labels.max()) + 1 if len(labels) else 0
    pix = np.asarray(pixels, dtype=np.float64)
    other = np.asarray(neighbour_pixels, dtype=np.float64).reshape(-1, 2)
    other_z = np.asarray(neighbour_depth_m, dtype=np.float64).reshape(-1)
    if len(pix):  # only the neighbour pixels a query below can reach
        reach = 2 * band_px
        box = np.all((other >= pix.min(axis=0) - reach) & (other <= pix.max(axis=0) + reach),
                     axis=1)
        other, other_z = other[box], other_z[box]
    read = np.isfinite(other_z) & (other_z > 0)
    if n_regions == 0 or not read.any():
        return np.zeros(n_regions, dtype=bool)
    near = cKDTree(other).query(pix, k=1)[0] <= band_px
    k = min(NEIGHBOUR_SAMPLES, int(read.sum()))
    dist, j = cKDTree(other[read]).query(pix, k=k)
    dist, j = dist.reshape(len(pix), k), j.reshape(len(pix), k)
    nz = np.where(dist <= 2 * band_px, other_z[read][j], np.nan)
    with warnings.catch_warnings():  # a pixel with no reading near: NaN, not the same
        warnings.simplefilter("ignore", RuntimeWarning)
        ref = np.nanmedian(nz, axis=1)
    z = np.asarray(depth_m, dtype=np.float64)
    same = np.isfinite(ref) & same_surface(z, np.where(np.isfinite(ref), ref, np.inf))
    count = np.maximum(np.bincount(labels, minlength=n_regions), 1)
    all_near = np.bincount(labels, weights=near, minlength=n_regions) == count
    share_same = np.bincount(labels, weights=same, minlength=n_regions) / count
    return all_near & (share_same >= 0.5)
