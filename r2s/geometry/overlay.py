"""Draw reconstructed objects over the input image, so a user can judge a fit at a glance.

The posed meshes are ray cast through the camera (so they occlude each other), each
object's rendered silhouette is tinted and outlined in its own colour, and the observed
instance masks are outlined in white: where the two outlines disagree, the fit is off.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy import ndimage

from PIL import Image, ImageDraw

from r2s.geometry.raycast import raycast_view
from r2s.pictures.annotate import label, mask_anchor

PALETTE = np.array([
    [230, 25, 75], [60, 180, 75], [255, 225, 25], [0, 130, 200], [245, 130, 48],
    [145, 30, 180], [70, 240, 240], [240, 50, 230], [210, 245, 60], [250, 190, 212],
    [0, 128, 128], [220, 190, 255], [170, 110, 40], [128, 0, 0], [170, 255, 195],
], dtype=np.uint8)
"""Distinct colours, cycled over objects in order."""


def _outline(mask: np.ndarray, width_px: int) -> np.ndarray:
    return mask & ~ndimage.binary_erosion(mask, iterations=max(width_px, 1))


def render_instances(meshes_world: list[trimesh.Trimesh], K: np.ndarray,
                     world_from_camera: np.ndarray, width: int, height: int) -> np.ndarray:
    """(H, W) int32 index of the visible mesh at each pixel, -1 where none."""
    if not meshes_world:
        return np.full((height, width), -1, dtype=np.int32)
    _, index, _ = raycast_view(meshes_world, K, world_from_camera, width, height)
    return index


def crop_box(masks: list[np.ndarray], margin: float = 0.2, min_margin_px: int = 10
             ) -> tuple[int, int, int, int]:
    """(r0, r1, c0, c1) around the union of (H, W) bool masks, grown by ``margin`` of its
    size; the whole image when the masks are empty."""
    union = np.logical_or.reduce([np.asarray(m, dtype=bool) for m in masks])
    height, width = union.shape
    rows, cols = np.nonzero(union)
    if len(rows) == 0:
        return 0, height, 0, width
    pr = max(int(margin * (rows.max() - rows.min())), min_margin_px)
    pc = max(int(margin * (cols.max() - cols.min())), min_margin_px)
    return (max(rows.min() - pr, 0), min(rows.max() + pr + 1, height),
            max(cols.min() - pc, 0), min(cols.max() + pc + 1, width))


UNMASKED_COLOR = np.array([255.0, 0.0, 255.0])
"""Magenta: things on the table that no mask covers."""


def fit_overlay(rgb: np.ndarray, rendered: np.ndarray, observed_masks: np.ndarray,
                observed_ids: list[int], alpha: float = 0.35, zoom_to_px: int | None = None,
                labels: dict[int, str] | None = None,
                unmasked: np.ndarray | None = None) -> np.ndarray:
    """(h, w, 3) uint8 picture of a fit.

    Parameters
    ----------
    rgb : (H, W, 3) uint8 input image.
    rendered : (H, W) int index into ``observed_ids`` of the rendered object, -1 = none.
    observed_masks : (H, W) int instance ids.
    observed_ids : the instance id of each rendered index.
    alpha : tint strength of the rendered silhouettes.
    zoom_to_px : when given, crop to the objects and enlarge the crop (by an integer
        factor, up to 4) so its longer side is about this many pixels.
    labels : when given, each object's id and label (``"3 mug"``) is written at the
        centroid of its observed mask (see :func:`label_anchors`).
    unmasked : (H, W) bool, when given: pixels of things no mask covers (tinted and
        outlined in magenta; r2s/geometry/unsegmented.py).
    """
    if unmasked is None:
        unmasked = np.zeros(observed_masks.shape, dtype=bool)
    if zoom_to_px is not None:
        r0, r1, c0, c1 = crop_box([rendered >= 0, observed_masks > 0, unmasked])
        factor = int(np.clip(zoom_to_px // max(r1 - r0, c1 - c0), 1, 4))

        def zoom(a: np.ndarray) -> np.ndarray:
            return np.repeat(np.repeat(a[r0:r1, c0:c1], factor, axis=0), factor, axis=1)

        rgb, rendered, observed_masks = zoom(rgb), zoom(rendered), zoom(observed_masks)
        unmasked = zoom(unmasked)
    out = rgb[:, :, :3].astype(np.float64).copy()
    line = max(1, int(round(min(rgb.shape[:2]) / 300)))
    out[unmasked] = 0.6 * out[unmasked] + 0.4 * UNMASKED_COLOR
    out[_outline(unmasked, line)] = UNMASKED_COLOR
    for k, obj_id in enumerate(observed_ids):
        color = PALETTE[k % len(PALETTE)].astype(np.float64)
        sil = rendered == k
        out[sil] = (1 - alpha) * out[sil] + alpha * color
        out[_outline(sil, line)] = color
        out[_outline(observed_masks == obj_id, line)] = 255.0
    out = np.clip(np.rint(out), 0, 255).astype(np.uint8)
    if labels is not None:
        out = _write_ids(out, observed_masks, observed_ids, labels)
    return out


def label_anchors(observed_masks: np.ndarray, ids: list[int]) -> dict[int, tuple[float, float]]:
    """Pixel ``(x, y)`` where each id's label goes: the centroid of its mask (the nearest mask
    pixel when the centroid falls outside, e.g. a mug's handle); ids absent from the masks
    are left out."""
    out = {}
    for obj_id in ids:
        at = mask_anchor(observed_masks == obj_id)
        if at is not None:
            out[int(obj_id)] = at
    return out


def _write_ids(image: np.ndarray, observed_masks: np.ndarray, ids: list[int],
               labels: dict[int, str]) -> np.ndarray:
    pil = Image.fromarray(image)
    draw = ImageDraw.Draw(pil)
    size_px = int(np.clip(min(image.shape[:2]) / 32, 11, 22))
    for k, obj_id in enumerate(ids):
        at = label_anchors(observed_masks, [obj_id]).get(int(obj_id))
        if at is None:
            continue
        colour = tuple(int(c) for c in PALETTE[k % len(PALETTE)])
        text = f"{obj_id} {labels.get(obj_id, '')}".strip()
        x, y = at
        r = max(3, size_px // 4)
        draw.ellipse([x - r, y - r, x + r, y + r], fill=colour, outline=(255, 255, 255))
        label(draw, (x, y - r - 0.8 * size_px), text, fg=(255, 255, 255), bg=(0, 0, 0),
              size_px=size_px, bounds=(pil.width, pil.height))
    return np.asarray(pil)
