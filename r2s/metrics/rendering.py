"""Rendering metrics at the input view: PSNR, SSIM (and LPIPS when its weights are local).

All scores are taken over the object pixels only (``object_mask``, normally
``input/masks.png > 0``). A render is albedo only (no lighting, see
:mod:`r2s.render.shade`), so it is compared with the observed radiance as is.

LPIPS needs network weights that r2s never downloads: it is computed only when the
``lpips`` package is importable and ``R2S_LPIPS_WEIGHTS`` names a file holding the
``state_dict()`` of an ``lpips.LPIPS(net="alex")`` model; otherwise it is reported as
``None`` with the reason.
"""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import trimesh
from PIL import Image, ImageDraw
from skimage.metrics import structural_similarity

from r2s.io.atomic import atomic_write_bytes
from r2s.io.input_scene import Camera
from r2s.pictures.annotate import colour_bar, heat_colour, label
from r2s.render.gbuffer import rasterize
from r2s.render.shade import mesh_colour, shade

PSNR_CAP_DB = 100.0
"""PSNR reported for identical images (a finite number keeps metrics.json valid JSON)."""

LPIPS_ENV = "R2S_LPIPS_WEIGHTS"
"""Environment variable naming a local LPIPS (AlexNet) state-dict file."""

ERROR_FULL_SCALE = 128.0
"""Mean absolute error (0-255 scale) shown at full brightness in the error panel."""


def _check(img_a: np.ndarray, img_b: np.ndarray, mask: np.ndarray) -> np.ndarray:
    if img_a.shape != img_b.shape or img_a.shape[:2] != mask.shape:
        raise ValueError(f"shape mismatch: {img_a.shape}, {img_b.shape}, mask {mask.shape}")
    return np.asarray(mask, dtype=bool)


def masked_psnr(img_a: np.ndarray, img_b: np.ndarray, mask: np.ndarray,
                data_range: float = 255.0) -> Optional[float]:
    """PSNR in dB over the pixels in ``mask`` (all channels).

    Parameters
    ----------
    img_a, img_b : (H, W, C) or (H, W) images on a 0..``data_range`` scale.
    mask : (H, W) bool.

    Returns
    -------
    PSNR in dB (at most :data:`PSNR_CAP_DB`), None when the mask is empty.
    """
    mask = _check(img_a, img_b, mask)
    if not mask.any():
        return None
    diff = img_a.astype(np.float64)[mask] - img_b.astype(np.float64)[mask]
    mse = float(np.mean(diff * diff))
    if mse <= 0:
        return PSNR_CAP_DB
    return float(min(10.0 * np.log10(data_range ** 2 / mse), PSNR_CAP_DB))


def ssim_map(img_a: np.ndarray, img_b: np.ndarray, mask: np.ndarray,
             data_range: float = 255.0) -> np.ndarray:
    """(H, W) scikit-image SSIM map (7x7 window, channels averaged) of ``img_b`` against ``img_a``.

    Outside ``mask`` ``img_b`` is replaced by ``img_a`` first, so windows that straddle the
    mask border compare the object pixels against a shared surround rather than against
    whatever the render put behind the object.
    """
    mask = _check(img_a, img_b, mask)
    a = img_a.astype(np.float64)
    b = np.where(mask[..., None] if a.ndim == 3 else mask, img_b.astype(np.float64), a)
    channel_axis = 2 if a.ndim == 3 else None
    _, smap = structural_similarity(a, b, data_range=data_range, channel_axis=channel_axis,
                                    full=True)
    return smap.mean(axis=2) if smap.ndim == 3 else smap


def masked_ssim(img_a: np.ndarray, img_b: np.ndarray, mask: np.ndarray,
                data_range: float = 255.0) -> Optional[float]:
    """Mean of :func:`ssim_map` over the pixels in ``mask``; None when the mask is empty.

    ``img_a``, ``img_b`` : (H, W, 3) or (H, W) on a 0..``data_range`` scale; mask (H, W) bool.
    """
    mask = _check(img_a, img_b, mask)
    if not mask.any():
        return None
    return float(ssim_map(img_a, img_b, mask, data_range)[mask].mean())


def lpips_unavailable_reason() -> Optional[str]:
    """Why LPIPS cannot be computed here, or None when it can."""
    path = os.environ.get(LPIPS_ENV)
    if not path:
        return (f"LPIPS needs pretrained network weights, which r2s does not download; set "
                f"{LPIPS_ENV} to a local lpips.LPIPS(net='alex') state_dict file")
    if not Path(path).is_file():
        return f"{LPIPS_ENV}={path}: no such file"
    try:
        import lpips  # noqa: F401
    except ImportError:
        return "the 'lpips' package is not installed"
    return None


def masked_lpips(img_a: np.ndarray, img_b: np.ndarray, mask: np.ndarray) -> float:
    """Mean of the spatial LPIPS (AlexNet) map over ``mask``; needs local weights (module doc).

    ``img_a``, ``img_b`` : (H, W, 3) uint8. Raises RuntimeError when LPIPS is unavailable.
    """
    reason = lpips_unavailable_reason()
    if reason is not None:
        raise RuntimeError(reason)
    import lpips
    import torch

    model = lpips.LPIPS(net="alex", pretrained=True, pnet_rand=True, spatial=True, verbose=False)
    state = torch.load(os.environ[LPIPS_ENV], map_location="cpu")
    model.load_state_dict(state, strict=True)
    model.eval()

    def tensor(img: np.ndarray) -> "torch.Tensor":
        t = torch.as_tensor(img.astype(np.float32) / 127.5 - 1.0)
        return t.permute(2, 0, 1)[None]

    b = np.where(mask[..., None], img_b, img_a)
    with torch.no_grad():
        dist = model(tensor(img_a), tensor(b))[0, 0].numpy()
    return float(dist[np.asarray(mask, dtype=bool)].mean())


def rendering_metrics(observed_rgb: np.ndarray, rendered_rgb: np.ndarray,
                      object_mask: np.ndarray) -> dict:
    """PSNR, SSIM and LPIPS of a render against the observation over the object pixels.

    Parameters
    ----------
    observed_rgb, rendered_rgb : (H, W, 3) uint8.
    object_mask : (H, W) bool, the pixels to score (e.g. ``masks > 0``).

    Returns
    -------
    ``{"psnr": dB | None, "ssim": float | None, "lpips": float | None,
    "lpips_reason": str | None, "object_pixels": int}``; ``lpips_reason`` says why LPIPS
    is None.
    """
    mask = np.asarray(object_mask, dtype=bool)
    out = {
        "psnr": masked_psnr(observed_rgb, rendered_rgb, mask),
        "ssim": masked_ssim(observed_rgb, rendered_rgb, mask),
        "lpips": None,
        "lpips_reason": lpips_unavailable_reason(),
        "object_pixels": int(mask.sum()),
    }
    if out["lpips_reason"] is None and mask.any():
        try:
            out["lpips"] = masked_lpips(observed_rgb, rendered_rgb, mask)
        except Exception as exc:  # a bad weights file must not break evaluation
            out["lpips_reason"] = f"LPIPS failed: {type(exc).__name__}: {exc}"
    return out


def render_scene_rgb(meshes_world: Sequence[trimesh.Trimesh], camera: Camera,
                     ids: Optional[Sequence[int]] = None) -> tuple[np.ndarray, np.ndarray]:
    """Albedo render of world-frame meshes (texture or vertex colours) from the camera.

    Parameters
    ----------
    meshes_world : meshes already placed in the world frame (``mesh.copy().apply_transform(
        world_from_object)`` keeps a texture's UVs).
    camera : :class:`r2s.io.input_scene.Camera` (OpenCV convention).
    ids : instance id of each mesh for the id map; default ``1..n``.

    Returns
    -------
    rgb : (H, W, 3) uint8, black where no mesh is seen.
    id_map : (H, W) int32 instance id of the visible mesh, 0 where none.
    """
    ids = list(range(1, len(meshes_world) + 1)) if ids is None else list(ids)
    gbuffer = rasterize(meshes_world, camera.K, camera.world_from_camera, camera.width,
                        camera.height)
    colours = [mesh_colour(m) for m in meshes_world]
    rgb = shade(gbuffer, [np.asarray(m.faces) for m in meshes_world], colours)
    lookup = np.asarray([0] + ids, dtype=np.int32)
    id_map = lookup[gbuffer.object_index + 1]
    return np.round(rgb * 255.0).astype(np.uint8), id_map


def _panel_label(img: np.ndarray, text: str) -> np.ndarray:
    pil = Image.fromarray(img)
    size_px = int(np.clip(img.shape[0] / 34, 8, 14))          # small images keep their pixels
    label(ImageDraw.Draw(pil), (0, 0), text, anchor="top-left", size_px=size_px)
    return np.asarray(pil)


def side_by_side(images: Sequence[np.ndarray], labels: Sequence[str],
                 object_mask: Optional[np.ndarray] = None) -> np.ndarray:
    """(H, (k + 1) W, 3) uint8: the k images in a row, then |last - first| as an error panel.

    The error panel shows the mean absolute error over channels (full brightness at
    :data:`ERROR_FULL_SCALE`) in red-yellow, inside ``object_mask`` only when given.
    """
    first = images[0].astype(np.float64)
    err = np.abs(images[-1].astype(np.float64) - first).mean(axis=2) / ERROR_FULL_SCALE
    err = np.clip(err, 0.0, 1.0)
    heat = heat_colour(err)
    if object_mask is not None:
        dim = (0.25 * first).astype(np.uint8)
        heat = np.where(np.asarray(object_mask, bool)[..., None], heat, dim)
    panels = [_panel_label(np.ascontiguousarray(im), lab) for im, lab in zip(images, labels)]
    panels.append(_panel_label(heat, "|error|" if object_mask is None
                               else "|error| on the objects (see the colour bar)"))
    return np.concatenate(panels, axis=1)


def error_colour_bar(width_px: int) -> np.ndarray:
    """(h, width_px, 3) uint8 colour bar of the error panel: mean absolute error over the
    RGB channels, 0 to :data:`ERROR_FULL_SCALE` 8-bit levels (saturated above)."""
    full = ERROR_FULL_SCALE
    return colour_bar(width_px, heat_colour, full,
                      "|error| panel: mean |observed - rendered| over RGB, 8-bit levels "
                      "(yellow: 128 or more)",
                      ticks=[0, full / 4, full / 2, 3 * full / 4, full], tick_format="{:.0f}")


def side_by_side_png(observed: np.ndarray, rendered: np.ndarray, path: Path,
                     object_mask: Optional[np.ndarray] = None) -> None:
    """Write observed | rendered | abs error (see :func:`side_by_side`) as a PNG, atomically,
    with the error panel's colour bar below (:func:`error_colour_bar`)."""
    buf = io.BytesIO()
    panels = side_by_side([observed, rendered], ["observed", "rendered"], object_mask)
    picture = np.concatenate([panels, error_colour_bar(panels.shape[1])], axis=0)
    Image.fromarray(picture).save(buf, format="PNG", compress_level=1)
    atomic_write_bytes(Path(path), buf.getvalue())
