"""Space the camera saw through, for carving a completed shape.

A point of a completed object that projects to a pixel with a valid depth reading and lies
in front of that reading by more than a margin is space the camera looked *past* (onto the
table, the wall, an object behind, or the object's own far side, e.g. the inner walls
behind an L-shaped block's notch): it is free and may not be material. The exception is
the mask's uncertain rim: pixels within ``band_px`` outside the object's kept pixels and
its own outermost ``rim_px`` ring, where mixed readings and mask errors put the reading
on the wrong surface. A sensor leaves holes along depth edges; a hole pixel within
``hole_fill_px`` of valid readings takes the farthest of them (the far side of the edge is
what the camera saw past), so that a completed shape does not spill through the hole ring
around an object. Larger holes and points outside the image or behind the camera are
unknown: hidden parts may go there, as they may behind nearer
objects (the reading is nearer than the point) and below the visible surface along the
ray.

Where the sensor read nothing, the instance masks still say what the camera saw: a pixel
that no mask covers (``masks`` given; a mask's own holes and notches narrower than about
``2 * close_px`` count as covered, and nothing within the object's rim band is tested) showed
the background, so a point of the object there would have been seen and segmented. Such
a point is carved unless a reading nearer than it (an unsegmented thing in front) could
hide it. Stereo sensors leave a band without depth beside every object (the projector's
shadow on the far side of the baseline) and dark or glossy tables read nothing; without
this test a completed shape spills into those bands.

The margin grows with depth like the axial noise of structured-light and stereo sensors:
``margin_m + margin_quadratic_m * (z / 1 m)^2``.

Where the camera sees the *table* (given the support plane: a pixel outside the object's
rim whose reading lies within ``table_tolerance_m + margin_quadratic_m * z^2`` of the
plane), the plane's own depth at that pixel replaces the noisy reading and the margin
shrinks to ``table_margin_m``: the fitted plane is exact to a fraction of a millimetre,
so a point a few millimetres above the visible table is carved. Without it the sensor
margin (about 1 cm at 1 m) leaves a skirt of material in front of every object whose
side bulges over its base (a lying can, a fruit): the walls extruded from the widest
outline down to the table hide table the camera saw.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Optional

import numpy as np
from scipy import ndimage

from r2s.geometry.camera import image_pixels

CARVE_MARGIN_M = 0.003
CARVE_MARGIN_QUADRATIC_M = 0.006
OWN_BAND_PX = 2
OWN_RIM_PX = 1
HOLE_FILL_PX = 2
TABLE_TOLERANCE_M = 0.003
TABLE_MARGIN_M = 0.002
MASK_CLOSE_PX = 2
OTHER_MARGIN_M = 0.0
"""In front of a reading deep inside another instance's mask, the margin: the mask says
the camera saw that object there, so no part of this one lies in front of it (its
reading's noise only decides how much of this object's hidden material next to that
surface is kept)."""
OTHER_MASK_MARGIN_M = 0.002
"""In front of a reading anywhere in another instance's mask outside the rim band, the
margin: the reading may be a mixed one at that object's outline or this object's surface
under a mask that bled onto it, so a little of the sensor's noise is allowed."""


@dataclass(frozen=True)
class CarveView:
    """One depth view and the pixels that are the object's own.

    K : (3, 3); world_from_camera : (4, 4) OpenCV camera; depth_m : (H, W) metres along
    the camera z axis, NaN / <= 0 = no reading; exempt : (H, W) bool, the mask's uncertain
    rim, where nothing is carved; own : (H, W) bool, the kept pixels (what hides a point
    from the camera there is the object itself); margin_m, margin_quadratic_m : see the
    module docstring; background : (H, W) bool or None, pixels the masks call background,
    outside the rim (the silhouette test of the module docstring); others_inner : (H, W)
    bool or None, pixels at least ``other_inner_px`` inside another instance's mask
    (:func:`seen_as_other`); others_any : (H, W) bool or None, every pixel of another
    instance's mask outside the rim band, carved with ``other_mask_margin_m``.
    """

    K: np.ndarray
    world_from_camera: np.ndarray
    depth_m: np.ndarray
    exempt: np.ndarray
    own: np.ndarray
    margin_m: float = CARVE_MARGIN_M
    margin_quadratic_m: float = CARVE_MARGIN_QUADRATIC_M
    table_depth_m: Optional[np.ndarray] = None
    table_margin_m: float = TABLE_MARGIN_M
    background: Optional[np.ndarray] = None
    others_inner: Optional[np.ndarray] = None
    other_margin_m: float = OTHER_MARGIN_M
    others_any: Optional[np.ndarray] = None
    other_mask_margin_m: float = OTHER_MASK_MARGIN_M


def carve_view(K: np.ndarray, world_from_camera: np.ndarray, depth_m: np.ndarray,
               own_pixels: np.ndarray, band_px: int = OWN_BAND_PX, rim_px: int = OWN_RIM_PX,
               hole_fill_px: int = HOLE_FILL_PX, margin_m: float = CARVE_MARGIN_M,
               margin_quadratic_m: float = CARVE_MARGIN_QUADRATIC_M,
               plane: Optional[tuple[np.ndarray, np.ndarray]] = None,
               table_tolerance_m: float = TABLE_TOLERANCE_M,
               table_margin_m: float = TABLE_MARGIN_M,
               masks: Optional[np.ndarray] = None,
               close_px: int = MASK_CLOSE_PX, other_inner_px: int = 0,
               other_mask_margin_m: Optional[float] = None) -> CarveView:
    """A :class:`CarveView` for an object whose kept observations are ``own_pixels``
    ((N, 2) int (row, col)): its rim (``band_px`` outside them, ``rim_px`` inside) is
    exempt from carving; holes are filled as the module docstring says. ``plane``
    (point (3,), unit normal (3,), world frame) enables the table test and ``masks``
    ((H, W) int instance ids, 0 = background) the silhouette test of the module
    docstring; with ``masks``, ``other_inner_px`` > 0 marks the pixels deep inside
    another instance's mask for :func:`seen_as_other`, and ``other_mask_margin_m`` (metres,
    None = off) carves in front of the readings of every other instance's pixel outside
    the rim band (module docstring)."""
    depth = fill_edge_holes(np.asarray(depth_m, dtype=np.float64), hole_fill_px)
    own = np.zeros(depth.shape, dtype=bool)
    pix = np.asarray(own_pixels, dtype=np.int64).reshape(-1, 2)
    own[pix[:, 0], pix[:, 1]] = True
    grown = ndimage.binary_dilation(own, iterations=int(band_px)) if band_px > 0 else own
    inner = ndimage.binary_erosion(own, iterations=int(rim_px)) if rim_px > 0 else own
    table = None
    if plane is not None:
        plane_z = plane_depth_m(K, world_from_camera, plane[0], plane[1], depth.shape)
        raw = np.asarray(depth_m, dtype=np.float64)
        tol = table_tolerance_m + margin_quadratic_m * np.square(np.nan_to_num(plane_z))
        with np.errstate(invalid="ignore"):
            sees_table = np.abs(raw - plane_z) < tol
        table = np.where(sees_table & ~grown, plane_z, np.nan)
    background = None if masks is None else ~_covered_once(masks, close_px) & ~grown
    others_inner = others_any = None
    if masks is not None and (other_inner_px > 0 or other_mask_margin_m is not None):
        labels = np.asarray(masks)
        others = _other_instances(labels, pix) & ~grown
        if other_inner_px > 0:
            others_inner = others & _uniform_within(labels, other_inner_px)
        if other_mask_margin_m is not None:
            others_any = others
    return CarveView(K=np.asarray(K, dtype=np.float64),
                     world_from_camera=np.asarray(world_from_camera, dtype=np.float64),
                     depth_m=depth, exempt=grown & ~inner, own=own, margin_m=float(margin_m),
                     margin_quadratic_m=float(margin_quadratic_m), table_depth_m=table,
                     table_margin_m=float(table_margin_m), background=background,
                     others_inner=others_inner, others_any=others_any,
                     other_mask_margin_m=(OTHER_MASK_MARGIN_M if other_mask_margin_m is None
                                          else float(other_mask_margin_m)))


def _uniform_within(labels: np.ndarray, inner_px: int) -> np.ndarray:
    """(H, W) bool: pixels with every pixel within ``inner_px`` (square window) of the same
    instance id: away from an outline, where a neighbour's bleed or an edge's mixed reading
    could be another object's surface."""
    size = 2 * int(inner_px) + 1
    return ndimage.minimum_filter(labels, size=size) == ndimage.maximum_filter(labels, size=size)


def _other_instances(masks: np.ndarray, own_pixels: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels of an instance other than the one most of ``own_pixels`` ((N, 2)
    row, col) lie in."""
    labels = np.asarray(masks)
    own_ids = labels[own_pixels[:, 0], own_pixels[:, 1]] if len(own_pixels) else labels[:0, 0]
    own_ids = own_ids[own_ids > 0]
    own_id = np.bincount(own_ids).argmax() if len(own_ids) else 0
    return (labels > 0) & (labels != own_id)


def covered_by_masks(masks: np.ndarray, close_px: int = MASK_CLOSE_PX) -> np.ndarray:
    """(H, W) bool: pixels some instance of ``masks`` ((H, W) int ids, 0 = background)
    covers, each instance's holes and gaps narrower than about ``2 * close_px`` filled (a
    segmenter's holes and notches). Background enclosed by *several* instances (the
    table between touching objects) stays background."""
    labels = np.asarray(masks)
    covered = labels > 0
    pad = max(int(close_px), 0) + 1
    for oid in np.unique(labels[covered]):
        rows, cols = np.nonzero(labels == oid)
        r0, r1 = max(rows.min() - pad, 0), min(rows.max() + pad + 1, labels.shape[0])
        c0, c1 = max(cols.min() - pad, 0), min(cols.max() + pad + 1, labels.shape[1])
        one = np.pad(labels[r0:r1, c0:c1] == oid, pad)
        if close_px > 0:
            one = ndimage.binary_closing(one, iterations=int(close_px))
        covered[r0:r1, c0:c1] |= ndimage.binary_fill_holes(one)[pad:-pad, pad:-pad]
    return covered


def _covered_once(masks: np.ndarray, close_px: int) -> np.ndarray:
    """:func:`covered_by_masks`, computed once per label image: init builds a view for
    every object of a scene from the same masks."""
    labels = np.ascontiguousarray(masks)
    return _covered_cached(labels.tobytes(), labels.shape, labels.dtype.str, int(close_px))


@functools.lru_cache(maxsize=2)
def _covered_cached(data: bytes, shape: tuple, dtype: str, close_px: int) -> np.ndarray:
    covered = covered_by_masks(np.frombuffer(data, dtype=dtype).reshape(shape), close_px)
    covered.setflags(write=False)
    return covered


def plane_depth_m(K: np.ndarray, world_from_camera: np.ndarray, plane_point: np.ndarray,
                  plane_normal: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) camera-z depth at which each pixel's ray meets the plane (world frame point
    and normal); NaN where the ray is parallel to it or meets it behind the camera."""
    height, width = shape
    cols, rows = np.meshgrid(np.arange(width, dtype=np.float64),
                             np.arange(height, dtype=np.float64))
    rays_cam = np.linalg.solve(np.asarray(K, dtype=np.float64),
                               np.stack([cols.ravel(), rows.ravel(), np.ones(cols.size)]))
    rot = np.asarray(world_from_camera, dtype=np.float64)[:3, :3]
    origin = np.asarray(world_from_camera, dtype=np.float64)[:3, 3]
    n = np.asarray(plane_normal, dtype=np.float64)
    along = n @ (rot @ rays_cam)  # (H*W,) normal component of each ray (camera z = 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = float(n @ (np.asarray(plane_point, dtype=np.float64) - origin)) / along
    t[~np.isfinite(t) | (t <= 0)] = np.nan
    return t.reshape(height, width)


def fill_edge_holes(depth_m: np.ndarray, radius_px: int) -> np.ndarray:
    """(H, W) ``depth_m`` with each hole pixel (NaN / <= 0) within ``radius_px`` (square
    window) of valid readings set to the largest of them."""
    depth = np.asarray(depth_m, dtype=np.float64)
    valid = np.isfinite(depth) & (depth > 0)
    if radius_px <= 0 or valid.all():
        return depth
    far = ndimage.maximum_filter(np.where(valid, depth, -np.inf), size=2 * radius_px + 1)
    out = depth.copy()
    fill = ~valid & np.isfinite(far)
    out[fill] = far[fill]
    return out


def _lookup(view: CarveView, points_world: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(in_image (N,) bool, row, col (N,) int (0 outside), z (N,) camera depth, d (N,)
    the reading at the pixel) of world points (N, 3)."""
    pts = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    ok, row, col, _, z = image_pixels(pts, view.K, view.world_from_camera,
                                      *view.depth_m.shape)
    return ok, row, col, z, view.depth_m[row, col]


def _sensor_margin_m(view: CarveView, d: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(N,) the sensor margin at readings ``d`` (N,) (module docstring), 0 m of depth where
    not ``valid``."""
    return view.margin_m + view.margin_quadratic_m * np.square(np.where(valid, d, 0.0))


def seen_as_other(view: CarveView, points_world: np.ndarray) -> np.ndarray:
    """(N,) bool: world points (N, 3) where the camera saw another object's surface at
    about their depth: at a pixel deep inside another instance's mask
    (``view.others_inner``), a valid reading no nearer than the point by more than the
    margin (so nothing hides the point there). Such a point, had it been this object's,
    would have been seen as this object. All False without ``others_inner``."""
    if view.others_inner is None:
        return np.zeros(len(np.asarray(points_world).reshape(-1, 3)), dtype=bool)
    ok, row, col, z, d = _lookup(view, points_world)
    read = ok & np.isfinite(d) & (d > 0) & view.others_inner[row, col]
    margin = _sensor_margin_m(view, d, read)
    with np.errstate(invalid="ignore"):
        return read & (d >= z - margin)


def hidden_by_other(view: CarveView, points_world: np.ndarray) -> np.ndarray:
    """(N,) bool: world points (N, 3) in the image that the camera could not see because
    something other than the object is in front of them (a valid reading nearer by more
    than the margin at a pixel that is not one of the object's kept pixels)."""
    ok, row, col, z, d = _lookup(view, points_world)
    valid = ok & np.isfinite(d) & (d > 0) & ~view.own[row, col]
    margin = _sensor_margin_m(view, d, valid)
    with np.errstate(invalid="ignore"):
        return valid & (d < z - margin)


def seen_free(view: CarveView, points_world: np.ndarray) -> np.ndarray:
    """(N,) bool: which world points (N, 3) the camera saw past (free space)."""
    ok, row, col, z, d = _lookup(view, points_world)
    read = ok & np.isfinite(d) & (d > 0)
    margin = _sensor_margin_m(view, d, read)
    with np.errstate(invalid="ignore"):
        free = read & ~view.exempt[row, col] & (z < d - margin)
        if view.table_depth_m is not None:
            table = view.table_depth_m[row, col]
            free |= ok & np.isfinite(table) & (z < table - view.table_margin_m)
        if view.background is not None:
            free |= ok & view.background[row, col] & ~(read & (d < z - margin))
        if view.others_inner is not None:
            free |= read & view.others_inner[row, col] & (z < d - view.other_margin_m)
        if view.others_any is not None:
            free |= read & view.others_any[row, col] & (z < d - view.other_mask_margin_m)
    return free
