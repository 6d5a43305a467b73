"""Pictures of a PyBullet scene seen by the scene's pinhole camera (OpenCV convention).

:func:`gl_view_matrix` and :func:`gl_projection_matrix` turn ``world_from_camera`` (OpenCV
camera: x right, y down, z forward) and ``K`` into the OpenGL matrices PyBullet's
``getCameraImage`` takes, so that a world point lands on the pixel ``K`` predicts (pixel
centres at integer coordinates, row 0 at the top).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import pybullet as pb
from PIL import Image, ImageDraw

GL_FROM_CV = np.diag([1.0, -1.0, -1.0, 1.0])
"""OpenCV camera frame (y down, z forward) -> OpenGL camera frame (y up, z backward)."""

PALETTE_RGB = np.array([
    [31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189],
    [140, 86, 75], [227, 119, 194], [188, 189, 34], [23, 190, 207], [127, 127, 127],
], dtype=np.float64) / 255.0
"""Object colours, indexed by ``id % 10``."""

SUPPORT_RGBA = (0.82, 0.82, 0.80, 1.0)


def colour_of(obj_id: int) -> tuple[float, float, float, float]:
    """RGBA in [0, 1] of an object id (stable across pictures)."""
    r, g, b = PALETTE_RGB[int(obj_id) % len(PALETTE_RGB)]
    return float(r), float(g), float(b), 1.0


def gl_view_matrix(world_from_camera: np.ndarray) -> np.ndarray:
    """(4, 4) OpenGL view matrix (world -> GL camera) from an OpenCV ``world_from_camera``."""
    return GL_FROM_CV @ np.linalg.inv(np.asarray(world_from_camera, dtype=np.float64))


def gl_projection_matrix(K: np.ndarray, width: int, height: int, near_m: float = 0.01,
                         far_m: float = 10.0) -> np.ndarray:
    """(4, 4) OpenGL projection for intrinsics ``K`` (3, 3) and an image of width x height.

    A point at OpenCV pixel ``(u, v)`` (pixel centres at integers) maps to normalised device
    coordinates ``x = 2 (u + 0.5) / W - 1``, ``y = 1 - 2 (v + 0.5) / H``.
    """
    K = np.asarray(K, dtype=np.float64)
    fx, fy = K[0, 0], K[1, 1]
    cx, cy = K[0, 2] + 0.5, K[1, 2] + 0.5
    n, f = float(near_m), float(far_m)
    return np.array([
        [2 * fx / width, 0.0, 1.0 - 2 * cx / width, 0.0],
        [0.0, 2 * fy / height, 2 * cy / height - 1.0, 0.0],
        [0.0, 0.0, -(f + n) / (f - n), -2 * f * n / (f - n)],
        [0.0, 0.0, -1.0, 0.0],
    ])


def pixels_from_gl(view: np.ndarray, projection: np.ndarray, points_world: np.ndarray,
                   width: int, height: int) -> np.ndarray:
    """(M, 2) OpenCV pixel coordinates (u, v) of world points (M, 3) through GL matrices."""
    pts = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    clip = (projection @ view @ np.c_[pts, np.ones(len(pts))].T).T
    ndc = clip[:, :3] / clip[:, 3:4]
    u = (ndc[:, 0] + 1.0) * width / 2.0 - 0.5
    v = (1.0 - ndc[:, 1]) * height / 2.0 - 0.5
    return np.stack([u, v], axis=1)


def scaled_intrinsics(K: np.ndarray, scale: float) -> np.ndarray:
    """``K`` for an image resized by ``scale`` (pixel-centre convention kept)."""
    out = np.asarray(K, dtype=np.float64).copy()
    out[0, 0] *= scale
    out[1, 1] *= scale
    out[0, 2] = (out[0, 2] + 0.5) * scale - 0.5
    out[1, 2] = (out[1, 2] + 0.5) * scale - 0.5
    return out


def colour_bodies(client: int, body_ids: dict[int, int], support_body: int | None = None) -> None:
    """Give each object body its id colour and the support a plain light grey."""
    for obj_id, body in body_ids.items():
        pb.changeVisualShape(body, -1, rgbaColor=colour_of(obj_id), physicsClientId=client)
    if support_body is not None:
        pb.changeVisualShape(support_body, -1, rgbaColor=SUPPORT_RGBA, textureUniqueId=-1,
                             physicsClientId=client)


TINY_RENDERER_PIXEL_SHIFT = (-0.5, 0.5)
"""(du, dv) added to the principal point for the tiny renderer, which samples the window
at pixel corners rather than centres (measured: silhouettes otherwise land +0.5 px in u and
-0.5 px in v from the pinhole projection; checked by tests/test_evaluate.py)."""


def _tiny_renderer_intrinsics(K: np.ndarray) -> np.ndarray:
    out = np.asarray(K, dtype=np.float64).copy()
    out[0, 2] += TINY_RENDERER_PIXEL_SHIFT[0]
    out[1, 2] += TINY_RENDERER_PIXEL_SHIFT[1]
    return out


def render(client: int, K: np.ndarray, world_from_camera: np.ndarray, width: int, height: int,
           near_m: float = 0.01, far_m: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """Picture from the OpenCV camera with PyBullet's tiny renderer.

    Returns
    -------
    rgb : (height, width, 3) uint8.
    body_ids : (height, width) int, PyBullet body id seen at each pixel, -1 for none.
    """
    view = gl_view_matrix(world_from_camera)
    proj = gl_projection_matrix(_tiny_renderer_intrinsics(K), width, height, near_m, far_m)
    _, _, rgba, _, seg = pb.getCameraImage(
        int(width), int(height),
        viewMatrix=view.T.reshape(-1).tolist(),          # PyBullet wants column-major
        projectionMatrix=proj.T.reshape(-1).tolist(),
        renderer=pb.ER_TINY_RENDERER, physicsClientId=client,
    )
    rgb = np.asarray(rgba, dtype=np.uint8).reshape(int(height), int(width), 4)[:, :, :3].copy()
    seg = np.asarray(seg, dtype=np.int64).reshape(int(height), int(width))
    # the segmentation buffer packs (link + 1) << 24 into the id for links; bases are plain
    body_ids = np.where(seg < 0, -1, seg & ((1 << 24) - 1))
    return rgb, body_ids


def render_rgb(client: int, K: np.ndarray, world_from_camera: np.ndarray, width: int,
               height: int, near_m: float = 0.01, far_m: float = 10.0) -> np.ndarray:
    """(height, width, 3) uint8 picture from the OpenCV camera (see :func:`render`)."""
    return render(client, K, world_from_camera, width, height, near_m, far_m)[0]


def side_by_side(images: Sequence[np.ndarray], titles: Sequence[str], caption: str,
                 gap_px: int = 4) -> np.ndarray:
    """Images (H, W, 3) uint8 in a row ``gap_px`` apart, a title above each, a caption below."""
    h = max(im.shape[0] for im in images)
    w = sum(im.shape[1] for im in images) + gap_px * (len(images) - 1)
    band = 18
    canvas = Image.new("RGB", (w, h + 2 * band), (255, 255, 255))
    draw = ImageDraw.Draw(canvas)
    x = 0
    for im, title in zip(images, titles):
        canvas.paste(Image.fromarray(im), (x, band))
        draw.text((x + 4, 3), title, fill=(0, 0, 0))
        x += im.shape[1] + gap_px
    draw.text((4, h + band + 3), caption, fill=(0, 0, 0))
    return np.asarray(canvas)
