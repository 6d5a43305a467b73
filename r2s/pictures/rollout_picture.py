"""``evaluate/rollout.png``: the judge's rollout seen by the input camera, with what moved.

Left: the first frame, every object labelled with its id and label at its silhouette.
Right: the last frame; objects that stayed are faded, each object that moved
(:mod:`r2s.metrics.motion`) is outlined in red and its silhouette at t = 0 in white
(before / after), an arrow joins its centre of mass at the start and at the end, and a
label gives id, label, displacement (mm) and turn (deg). Below: the judge's summary and
the list of moved objects.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
from PIL import Image, ImageDraw

from r2s.geometry.camera import project
from r2s.metrics.motion import MOVED_ROTATION_DEG, MOVED_TRANSLATION_M, ObjectMotion
from r2s.pictures.annotate import arrow, font, label, mask_anchor, outline, text_size

MOVED_RGB = (230, 20, 20)
BEFORE_RGB = (255, 255, 255)
STILL_BG = (60, 60, 60)
STILL_FADE = 0.35
"""Objects that did not move are faded to this fraction of their colour on the last frame."""
FADE_RGB = (200, 200, 196)


@dataclass(frozen=True)
class Frame:
    """One rendered frame: ``rgb`` (H, W, 3) uint8 and ``object_ids`` (H, W) int, the object
    id seen at each pixel (-1 for none or the support)."""

    rgb: np.ndarray
    object_ids: np.ndarray


@dataclass(frozen=True)
class MotionLabel:
    """What the picture writes for one object: ``highlighted`` objects moved."""

    id: int
    text: str
    highlighted: bool


def motion_labels(motions: Sequence[ObjectMotion], unstable_ids: Sequence[int] = ()
                  ) -> list[MotionLabel]:
    """The label of each object on the last frame, in ``motions`` order.

    A moved object reads ``"3 mug: 12.4 mm, 3.1 deg"`` (plus ``", unstable"`` when the
    judge says so); an object that stayed reads its id only.
    """
    unstable = {int(i) for i in unstable_ids}
    out = []
    for m in motions:
        if m.moved or m.id in unstable:
            text = m.caption + (", unstable" if m.id in unstable else "")
            out.append(MotionLabel(m.id, text, True))
        else:
            out.append(MotionLabel(m.id, str(m.id), False))
    return out


def moved_summary(motions: Sequence[ObjectMotion], unstable_ids: Sequence[int] = ()) -> str:
    """One line naming the objects that moved, the largest first."""
    labels = {lab.id: lab for lab in motion_labels(motions, unstable_ids)}
    moved = sorted((m for m in motions if labels[m.id].highlighted),
                   key=lambda m: -m.displacement_mm)
    if not moved:
        return (f"no object moved (every COM < {1000 * MOVED_TRANSLATION_M:.0f} mm and "
                f"turn < {MOVED_ROTATION_DEG:.0f} deg)")
    return "moved (red): " + ";  ".join(labels[m.id].text for m in moved)


def _pixel(point_m: np.ndarray, K: np.ndarray, world_from_camera: np.ndarray
           ) -> Optional[np.ndarray]:
    uv, z = project(np.asarray(point_m, float).reshape(1, 3), K, world_from_camera)
    return None if z[0] <= 0 or not np.all(np.isfinite(uv)) else uv[0]


def _panel(frame: Frame, title: str) -> tuple[Image.Image, ImageDraw.ImageDraw]:
    img = Image.fromarray(np.ascontiguousarray(frame.rgb))
    draw = ImageDraw.Draw(img)
    label(draw, (0, 0), title, anchor="top-left", size_px=14)
    return img, draw


def _first_panel(frame: Frame, motions: Sequence[ObjectMotion], K: np.ndarray,
                 world_from_camera: np.ndarray, title: str) -> Image.Image:
    img, draw = _panel(frame, title)
    size = (img.width, img.height)
    for m in motions:
        at = mask_anchor(frame.object_ids == m.id) or _pixel(m.com_start_m, K, world_from_camera)
        if at is not None:
            label(draw, at, f"{m.id} {m.label}".strip(), size_px=13, bounds=size)
    return img


def _last_panel(first: Frame, last: Frame, motions: Sequence[ObjectMotion],
                labels: dict[int, MotionLabel], K: np.ndarray, world_from_camera: np.ndarray,
                title: str) -> Image.Image:
    rgb = last.rgb.copy()
    line = max(2, round(min(rgb.shape[:2]) / 200))
    still = np.isin(last.object_ids, [m.id for m in motions if not labels[m.id].highlighted])
    rgb[still] = np.round(STILL_FADE * rgb[still] + (1 - STILL_FADE) * np.asarray(FADE_RGB))
    for m in motions:
        if labels[m.id].highlighted:
            rgb[outline(first.object_ids == m.id, line)] = BEFORE_RGB
            rgb[outline(last.object_ids == m.id, line)] = MOVED_RGB
    img, draw = _panel(Frame(rgb, last.object_ids), title)
    size = (img.width, img.height)
    for m in motions:
        lab = labels[m.id]
        end = _pixel(m.com_end_m, K, world_from_camera)
        if lab.highlighted:
            start = _pixel(m.com_start_m, K, world_from_camera)
            if start is not None and end is not None:
                arrow(draw, start, end, MOVED_RGB, width_px=line + 1)
            at = end if end is not None else mask_anchor(last.object_ids == m.id)
            if at is not None:
                label(draw, (at[0], at[1] - 22), lab.text, bg=MOVED_RGB, size_px=13, bounds=size)
        else:
            at = mask_anchor(last.object_ids == m.id) or end
            if at is not None:
                label(draw, at, lab.text, bg=STILL_BG, size_px=12, bounds=size)
    return img


def rollout_picture(first: Frame, last: Frame, motions: Sequence[ObjectMotion], K: np.ndarray,
                    world_from_camera: np.ndarray, duration_s: float, caption: str,
                    unstable_ids: Sequence[int] = (), gap_px: int = 4) -> np.ndarray:
    """(H', W', 3) uint8 picture: the two annotated frames side by side, text below.

    ``K`` (3, 3) and ``world_from_camera`` (4, 4, OpenCV) are the camera of both frames
    (``K`` at the frames' resolution).
    """
    labels = {lab.id: lab for lab in motion_labels(motions, unstable_ids)}
    left = _first_panel(first, motions, K, world_from_camera, "t = 0 s: objects by id")
    right = _last_panel(first, last, motions, labels, K, world_from_camera,
                        f"t = {duration_s:.1f} s: moved objects in red "
                        "(white: outline at t = 0)")
    lines = [caption, moved_summary(motions, unstable_ids)]
    line_h = text_size("Ag", 14)[1] + 8
    w = left.width + right.width + gap_px
    h = max(left.height, right.height)
    canvas = Image.new("RGB", (w, h + line_h * len(lines) + 6), (255, 255, 255))
    canvas.paste(left, (0, 0))
    canvas.paste(right, (left.width + gap_px, 0))
    draw = ImageDraw.Draw(canvas)
    for k, text in enumerate(lines):
        colour = MOVED_RGB if k == 1 and "moved (red)" in text else (0, 0, 0)
        draw.text((6, h + 4 + k * line_h), text, fill=colour, font=font(14))
    return np.asarray(canvas)
