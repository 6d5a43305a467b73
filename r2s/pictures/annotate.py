"""Drawing helpers on (H, W, 3) uint8 images: readable labels, arrows, outlines, colour bars.

Text uses DejaVu Sans (shipped with matplotlib) so labels stay legible at any size; PIL's
bitmap font is the fallback.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Callable, Optional, Sequence

import numpy as np
from PIL import Image, ImageDraw, ImageFont
from scipy import ndimage

RGB = tuple[int, int, int]


@lru_cache(maxsize=8)
def font(size_px: int = 14) -> ImageFont.ImageFont:
    """A scalable sans-serif font of ``size_px`` (PIL's default font if none is found)."""
    try:
        from matplotlib import font_manager

        return ImageFont.truetype(font_manager.findfont("DejaVu Sans"), size_px)
    except Exception:  # no matplotlib font or no FreeType: the bitmap font still draws
        return ImageFont.load_default()


def text_size(text: str, size_px: int = 14) -> tuple[int, int]:
    """(width, height) in pixels of ``text`` in :func:`font`."""
    box = ImageDraw.Draw(Image.new("RGB", (1, 1))).textbbox((0, 0), text, font=font(size_px))
    return int(box[2] - box[0]), int(box[3] - box[1])


def label(draw: ImageDraw.ImageDraw, xy: Sequence[float], text: str, fg: RGB = (255, 255, 255),
          bg: RGB = (0, 0, 0), size_px: int = 14, anchor: str = "centre",
          bounds: Optional[tuple[int, int]] = None) -> tuple[int, int, int, int]:
    """Text on a filled box at ``xy`` (pixel x, y); ``anchor`` "centre" or "top-left".

    The box is kept inside ``bounds`` (width, height) when given. Returns the box
    ``(x0, y0, x1, y1)``.
    """
    w, h = text_size(text, size_px)
    pad = max(2, size_px // 5)
    x, y = float(xy[0]), float(xy[1])
    if anchor == "centre":
        x, y = x - w / 2 - pad, y - h / 2 - pad
    x0, y0 = int(round(x)), int(round(y))
    x1, y1 = x0 + w + 2 * pad, y0 + h + 2 * pad + size_px // 4
    if bounds is not None:
        dx = min(0, bounds[0] - 1 - x1) - min(0, x0)
        dy = min(0, bounds[1] - 1 - y1) - min(0, y0)
        x0, x1, y0, y1 = x0 + dx, x1 + dx, y0 + dy, y1 + dy
    draw.rectangle([x0, y0, x1, y1], fill=bg)
    draw.text((x0 + pad, y0 + pad), text, fill=fg, font=font(size_px))
    return x0, y0, x1, y1


def arrow(draw: ImageDraw.ImageDraw, start: Sequence[float], end: Sequence[float], colour: RGB,
          width_px: int = 3, head_px: float = 12.0) -> None:
    """A straight arrow from ``start`` to ``end`` (pixel x, y) with a filled head at ``end``."""
    p0, p1 = np.asarray(start, float), np.asarray(end, float)
    d = p1 - p0
    length = float(np.linalg.norm(d))
    if length < 1e-6:
        r = width_px + 2
        draw.ellipse([p1[0] - r, p1[1] - r, p1[0] + r, p1[1] + r], outline=colour,
                     width=width_px)
        return
    u = d / length
    head = min(head_px, 0.6 * length + 4)
    base = p1 - head * u
    n = np.array([-u[1], u[0]])
    draw.line([tuple(p0), tuple(base)], fill=colour, width=width_px)
    draw.polygon([tuple(p1), tuple(base + 0.5 * head * n), tuple(base - 0.5 * head * n)],
                 fill=colour)


def outline(mask: np.ndarray, width_px: int = 2) -> np.ndarray:
    """(H, W) bool: the pixels of ``mask`` within ``width_px`` of its border."""
    mask = np.asarray(mask, dtype=bool)
    return mask & ~ndimage.binary_erosion(mask, iterations=max(int(width_px), 1))


def mask_anchor(mask: np.ndarray) -> Optional[tuple[float, float]]:
    """(x, y) pixel where a label for ``mask`` goes: its centroid, or, when the centroid falls
    outside a non-convex mask, the mask pixel nearest to it. None for an empty mask."""
    rows, cols = np.nonzero(np.asarray(mask, dtype=bool))
    if len(rows) == 0:
        return None
    r, c = rows.mean(), cols.mean()
    ri, ci = int(round(r)), int(round(c))
    if mask[ri, ci]:
        return float(c), float(r)
    k = int(np.argmin((rows - r) ** 2 + (cols - c) ** 2))
    return float(cols[k]), float(rows[k])


def heat_colour(values: np.ndarray) -> np.ndarray:
    """(..., 3) uint8 black-red-yellow colour of ``values`` in [0, 1] (clipped)."""
    v = np.clip(np.asarray(values, dtype=np.float64), 0.0, 1.0)
    rgb = np.stack([np.clip(2 * v, 0, 1), np.clip(2 * v - 1, 0, 1), np.zeros_like(v)], axis=-1)
    return np.round(rgb * 255).astype(np.uint8)


def colour_bar(width_px: int, colour_of: Callable[[np.ndarray], np.ndarray], vmax: float,
               title: str, ticks: Sequence[float], height_px: int = 46,
               tick_format: str = "{:g}") -> np.ndarray:
    """(height_px, width_px, 3) uint8 strip: a horizontal colour ramp from 0 to ``vmax``
    (``colour_of`` maps values in [0, 1] to uint8 RGB), tick labels below, ``title`` left."""
    canvas = Image.new("RGB", (int(width_px), int(height_px)), (255, 255, 255))
    draw = ImageDraw.Draw(canvas)
    title_w, _ = text_size(title, 13)
    if title_w + 16 > width_px / 2:          # too narrow for the title: the ramp alone
        title, title_w = "", -6
    x0 = title_w + 16
    x1 = int(width_px) - 20
    bar_h = 14
    y0 = 6
    ramp = colour_of(np.linspace(0.0, 1.0, max(x1 - x0, 2)))
    canvas.paste(Image.fromarray(np.repeat(ramp[None], bar_h, axis=0)), (x0, y0))
    draw.rectangle([x0 - 1, y0 - 1, x1, y0 + bar_h], outline=(0, 0, 0))
    if title:
        draw.text((6, y0), title, fill=(0, 0, 0), font=font(13))
    for t in ticks:
        x = x0 + (x1 - x0 - 1) * float(t) / float(vmax)
        draw.line([(x, y0 + bar_h), (x, y0 + bar_h + 4)], fill=(0, 0, 0), width=1)
        text = tick_format.format(t)
        w, _ = text_size(text, 12)
        draw.text((x - w / 2, y0 + bar_h + 6), text, fill=(0, 0, 0), font=font(12))
    return np.asarray(canvas)
