"""Pose updates: a small rotation about the object's centroid plus a translation.

The optimised pose of object m is ``world_from_object = A_m @ world_from_object_init``
with ``A_m(p) = R(omega_m) (p - c_m) + c_m + t_m``: ``omega_m`` (3,) axis-angle,
``t_m`` (3,) metres, ``c_m`` (3,) the object's centroid in the world at its init pose.
"""

from __future__ import annotations

import numpy as np
import torch


def axis_angle_to_matrix(omega: torch.Tensor) -> torch.Tensor:
    """(M, 3) axis-angle -> (M, 3, 3) rotation matrices (Rodrigues, smooth at 0)."""
    theta2 = (omega * omega).sum(dim=-1, keepdim=True)
    theta = torch.sqrt(theta2.clamp_min(1e-24))
    small = theta2 < 1e-8
    # sin(t)/t and (1 - cos t)/t^2 with their Taylor series near 0
    a = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24.0, (1.0 - torch.cos(theta)) / theta2.clamp_min(1e-24))
    zero = torch.zeros_like(omega[:, 0])
    k = torch.stack([
        torch.stack([zero, -omega[:, 2], omega[:, 1]], dim=-1),
        torch.stack([omega[:, 2], zero, -omega[:, 0]], dim=-1),
        torch.stack([-omega[:, 1], omega[:, 0], zero], dim=-1),
    ], dim=-2)
    eye = torch.eye(3, dtype=omega.dtype, device=omega.device).expand_as(k)
    return eye + a[..., None] * k + b[..., None] * (k @ k)


def move_points(points_world: torch.Tensor, centres: torch.Tensor, rot: torch.Tensor,
                trans: torch.Tensor) -> torch.Tensor:
    """Apply A_m to (M, N, 3) world points of each object (centres, trans (M, 3); rot (M, 3, 3))."""
    rel = points_world - centres[:, None, :]
    return rel @ rot.transpose(1, 2) + (centres + trans)[:, None, :]


def updated_poses(init_world_from_object: np.ndarray, centres: np.ndarray, omega: np.ndarray,
                  trans: np.ndarray) -> np.ndarray:
    """(M, 4, 4) world_from_object after the update (numpy, float64)."""
    rot = axis_angle_to_matrix(torch.as_tensor(omega, dtype=torch.float64)).numpy()
    out = np.empty_like(np.asarray(init_world_from_object, dtype=np.float64))
    for m in range(len(out)):
        a = np.eye(4)
        a[:3, :3] = rot[m]
        a[:3, 3] = centres[m] + trans[m] - rot[m] @ centres[m]
        out[m] = a @ init_world_from_object[m]
    return out
