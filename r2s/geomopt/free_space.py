"""A differentiable free-space (silhouette) term for the pose optimisation.

A surface sample of an object that projects to a pixel where the camera saw a valid
surface at least ``margin_m`` *behind* it, farther than ``band_px`` from the object's own
mask, lies in space the camera saw empty (it would have hidden what the camera saw). Its
cost is how far its projection lies outside that band, in metres at its own depth:

    cost = relu(D_own(u, v) - band_px) * z / f

with ``D_own`` the distance transform of the object's mask (pixels), read bilinearly so
the gradient moves the projection towards the mask (sideways to the ray), never towards
or away from the camera (``z`` is held constant in the gradient). Which samples pay is
decided on the observed depth image at the nearest pixel; pixels without a depth reading,
outside the image, or where something was seen in front of the sample (an occluder) say
nothing. This is the measure of :func:`r2s.metrics.observation.free_space_map` made
differentiable in the poses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from scipy import ndimage


@dataclass(frozen=True)
class ObservedView:
    """What the camera saw, per object of an optimisation problem (M objects).

    K : (3, 3); world_from_camera : (4, 4) OpenCV camera.
    depth_m : (H, W) observed depth, NaN = no reading.
    mask_distance_px : (M, H, W) float32 distance of each pixel to the nearest pixel of
        object m's mask (0 inside; a large value everywhere for an empty mask).
    """

    K: np.ndarray
    world_from_camera: np.ndarray
    depth_m: np.ndarray
    mask_distance_px: np.ndarray


def observed_view(K: np.ndarray, world_from_camera: np.ndarray, depth_m: np.ndarray,
                  masks: np.ndarray, ids: list[int]) -> ObservedView:
    """The :class:`ObservedView` of objects ``ids`` from the input's depth and masks (H, W)."""
    masks = np.asarray(masks)
    height, width = masks.shape
    far = float(height + width)
    dist = np.empty((len(ids), height, width), dtype=np.float32)
    for k, i in enumerate(ids):
        own = masks == i
        dist[k] = ndimage.distance_transform_edt(~own) if own.any() else far
    depth = np.asarray(depth_m, dtype=np.float64)
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan)
    return ObservedView(np.asarray(K, dtype=np.float64),
                        np.asarray(world_from_camera, dtype=np.float64), depth, dist)


class FreeSpaceTerm:
    """The term of :mod:`this module <r2s.geomopt.free_space>` on (M, N, 3) world samples."""

    def __init__(self, view: ObservedView, band_px: float = 2.0, margin_m: float = 0.015,
                 dtype: torch.dtype = torch.float32):
        self.dtype = dtype
        cam = torch.as_tensor(view.world_from_camera, dtype=dtype)
        self.rot_cw = cam[:3, :3].T          # camera_from_world rotation
        self.centre = cam[:3, 3]
        k = view.K
        self.fx, self.fy, self.cx, self.cy = (float(k[0, 0]), float(k[1, 1]),
                                              float(k[0, 2]), float(k[1, 2]))
        self.skew = float(k[0, 1])
        self.height, self.width = view.depth_m.shape
        self.depth = torch.as_tensor(np.nan_to_num(view.depth_m, nan=-1.0), dtype=dtype)
        self.distance = torch.as_tensor(view.mask_distance_px, dtype=dtype)[:, None]  # (M,1,H,W)
        self.band_px = float(band_px)
        self.margin_m = float(margin_m)

    def __call__(self, world: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Cost (M, N) in metres of every sample, and (M, N) bool: which samples violate."""
        pc = (world - self.centre) @ self.rot_cw.T
        z = pc[..., 2]
        zs = z.detach().clamp_min(1e-6)
        u = (self.fx * pc[..., 0] + self.skew * pc[..., 1]) / zs + self.cx
        v = self.fy * pc[..., 1] / zs + self.cy
        with torch.no_grad():
            col, row = torch.round(u).long(), torch.round(v).long()
            inside = (z > 0) & (col >= 0) & (col < self.width) & (row >= 0) & (row < self.height)
            obs = self.depth[row.clamp(0, self.height - 1), col.clamp(0, self.width - 1)]
            seen_past = inside & (obs > 0) & (obs >= z + self.margin_m)
        grid = torch.stack([2.0 * u / max(self.width - 1, 1) - 1.0,
                            2.0 * v / max(self.height - 1, 1) - 1.0], dim=-1)[:, :, None, :]
        dist = F.grid_sample(self.distance, grid, mode="bilinear", padding_mode="border",
                             align_corners=True)[:, 0, :, 0]
        over = torch.relu(dist - self.band_px)
        violating = seen_past & (over > 1e-6)
        cost = torch.where(violating, over * zs / self.fx, torch.zeros_like(over))
        return cost, violating
