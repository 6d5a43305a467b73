"""The free-space test of a posed model against one depth view.

Where the camera sees *past* a model point (the observed surface at its pixel is farther
away than the point) and the pixel is not the instance's, the model cannot be there: it
would have hidden what the camera saw. Such points are pulled towards the nearest pixel
of the instance's mask. Pixels where something is *in front of* the model say nothing
(occlusion), nor do pixels outside the image. A pixel without a depth reading counts as
seen past (the camera saw nothing there), except inside another instance's mask when those
masks are given: that instance is what the camera saw there, and this one may be hidden
behind it (dark or glossy occluders often read no depth).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
from scipy import ndimage

from r2s.geometry.camera import image_pixels, transform_points


@dataclass(frozen=True)
class ViewConstraint:
    """What the camera saw around one instance, for the free-space (silhouette) term.

    Build it with :func:`view_constraint`. Arrays are cropped to ``window`` (rows
    ``r0:r1``, columns ``c0:c1``) around the instance.

    Attributes
    ----------
    K : (3, 3); world_from_camera : (4, 4) OpenCV camera.
    depth_m : (H, W) observed depth (full image), NaN = no reading.
    own : (h, w) bool, the instance's mask in the window.
    nearest : (2, h, w) int, window (row, col) of the nearest ``own`` pixel of each pixel.
    window : (r0, r1, c0, c1) in full-image pixels.
    image_size : (height, width) of the full image.
    margin_px : distance from the mask (pixels) beyond which a projection is a violation.
    others : (h, w) bool, the other instances' masks in the window, or None (then a pixel
        without a depth reading is seen past wherever it is).
    """

    K: np.ndarray
    world_from_camera: np.ndarray
    depth_m: np.ndarray
    own: np.ndarray
    nearest: np.ndarray
    window: tuple[int, int, int, int]
    image_size: tuple[int, int]
    margin_px: float = 1.5
    others: Optional[np.ndarray] = None


def view_constraint(K: np.ndarray, world_from_camera: np.ndarray, depth_m: np.ndarray,
                    own_mask: np.ndarray, margin_px: float = 1.5,
                    other_masks: Optional[np.ndarray] = None) -> ViewConstraint:
    """Precompute the free-space test of one instance.

    Parameters
    ----------
    K : (3, 3); world_from_camera : (4, 4); depth_m : (H, W) metres, NaN = no reading.
    own_mask : (H, W) bool, the instance's mask (at least one pixel).
    margin_px : a model point violates free space only when its projection is farther
        than this from every mask pixel centre. Points on the true outline can be more
        than a pixel from the nearest pixel that sees the object (corners, thin parts),
        so below about 1.5 px the term pulls a correct pose inward; raise it for masks
        whose edges are uncertain.
    other_masks : (H, W) bool, the pixels of the other instances, or None: where given, a
        pixel there without a depth reading says nothing (the other instance may hide this
        one); elsewhere it counts as seen past.
    """
    own_mask = np.asarray(own_mask, dtype=bool)
    rows, cols = np.nonzero(own_mask)
    if len(rows) == 0:
        raise ValueError("view_constraint needs a non-empty mask")
    height, width = own_mask.shape
    pad_r = max(int(rows.max() - rows.min()), 40)
    pad_c = max(int(cols.max() - cols.min()), 40)
    r0, r1 = max(rows.min() - pad_r, 0), min(rows.max() + pad_r + 1, height)
    c0, c1 = max(cols.min() - pad_c, 0), min(cols.max() + pad_c + 1, width)
    own = own_mask[r0:r1, c0:c1]
    _, nearest = ndimage.distance_transform_edt(~own, return_indices=True)
    return ViewConstraint(K=np.asarray(K, dtype=np.float64),
                          world_from_camera=np.asarray(world_from_camera, dtype=np.float64),
                          depth_m=np.asarray(depth_m, dtype=np.float64),
                          own=own, nearest=nearest.astype(np.int64),
                          window=(int(r0), int(r1), int(c0), int(c1)),
                          image_size=(height, width), margin_px=float(margin_px),
                          others=None if other_masks is None
                          else np.asarray(other_masks, dtype=bool)[r0:r1, c0:c1])


def free_space_violations(view: ViewConstraint, points_world: np.ndarray,
                          normals_world: np.ndarray, tolerance_m: float = 0.01
                          ) -> tuple[np.ndarray, np.ndarray, int]:
    """Which model points the camera sees past, and where each should be.

    Parameters
    ----------
    view : the instance's :class:`ViewConstraint`.
    points_world, normals_world : (N, 3) model surface samples and their outward normals.
    tolerance_m : how far behind a point the observed surface must be.

    Returns
    -------
    violating : (N,) bool; only points facing the camera and projecting into the image
        are tested.
    targets_world : (V, 3) for the V violating points: the ray through the nearest mask
        pixel centre, at the point's camera depth.
    tested : number of points tested.
    """
    xw = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    cam = view.world_from_camera[:3, 3]
    facing = np.einsum("nj,nj->n", np.asarray(normals_world, dtype=np.float64), cam - xw) > 0
    height, width = view.image_size
    ok, row, col, uv, z = image_pixels(xw, view.K, view.world_from_camera, height, width)
    ok &= facing
    r0, r1, c0, c1 = view.window
    rr = np.clip(row - r0, 0, r1 - r0 - 1)
    cc = np.clip(col - c0, 0, c1 - c0 - 1)
    nr = view.nearest[0, rr, cc] + r0
    nc = view.nearest[1, rr, cc] + c0
    uv_safe = np.where(ok[:, None], uv, 0.0)
    off_mask = np.hypot(uv_safe[:, 0] - nc, uv_safe[:, 1] - nr) > view.margin_px
    d = view.depth_m[np.clip(row, 0, height - 1), np.clip(col, 0, width - 1)]
    no_reading = ~np.isfinite(d)
    if view.others is not None:
        in_window = (row >= r0) & (row < r1) & (col >= c0) & (col < c1)
        no_reading &= ~(in_window & view.others[rr, cc])
    seen_past = no_reading | (d > z + tolerance_m)
    viol = ok & off_mask & seen_past
    nr, nc = nr[viol], nc[viol]
    pix = np.stack([nc, nr, np.ones_like(nc)], axis=1).astype(np.float64)
    target_cam = (pix @ np.linalg.inv(view.K).T) * z[viol, None]
    return viol, transform_points(view.world_from_camera, target_cam), int(ok.sum())
