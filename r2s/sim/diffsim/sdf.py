"""Differentiable look-up of a signed distance grid (trilinear), for the simulator's obstacles.

Grid convention: ``values[i, j, k]`` is the signed distance (metres, negative inside) at the
grid node ``origin + voxel_size_m * (i, j, k)`` in the obstacle's object frame. A point
outside the grid box is clamped onto it and the clamping distance is added, so far points
read a positive distance that grows with the distance to the grid.
"""

from __future__ import annotations

import torch

from r2s.sim.diffsim.rotation import safe_norm


def trilinear_sdf(values: torch.Tensor, origin: torch.Tensor, voxel_size_m: float,
                  points: torch.Tensor) -> torch.Tensor:
    """Signed distance at ``points`` by trilinear interpolation of ``values``.

    Parameters
    ----------
    values : (X, Y, Z) signed distances at the grid nodes, metres.
    origin : (3,) position of node (0, 0, 0), same frame as ``points``.
    voxel_size_m : node spacing.
    points : (N, 3) query points.

    Returns
    -------
    (N,) signed distances; differentiable w.r.t. ``points``, ``values`` and ``origin``.
    """
    shape = torch.tensor(values.shape, device=points.device)
    upper = (shape - 1).to(points.dtype) * voxel_size_m
    local = points - origin
    clamped = torch.minimum(torch.clamp(local, min=0.0), upper)
    outside = safe_norm(local - clamped) - 1e-12
    u = clamped / voxel_size_m
    base = torch.clamp(torch.floor(u.detach()).long(), min=0)
    base = torch.minimum(base, shape - 2)
    frac = u - base.to(u.dtype)
    nx, ny, nz = values.shape
    flat = values.reshape(-1)
    i, j, k = base.unbind(-1)
    fx, fy, fz = frac.unbind(-1)
    out = torch.zeros_like(fx)
    for di in (0, 1):
        wx = fx if di else 1.0 - fx
        for dj in (0, 1):
            wy = fy if dj else 1.0 - fy
            for dk in (0, 1):
                wz = fz if dk else 1.0 - fz
                idx = ((i + di) * ny + (j + dj)) * nz + (k + dk)
                out = out + wx * wy * wz * flat[idx]
    return out + outside


def sdf_lookup(values: torch.Tensor, origin: torch.Tensor, voxel_size_m: float,
               points: torch.Tensor) -> torch.Tensor:
    """The look-up the simulator uses (the shared one when present, else :func:`trilinear_sdf`)."""
    return _LOOKUP(values, origin, voxel_size_m, points)


def sdf_gradient(values: torch.Tensor, origin: torch.Tensor, voxel_size_m: float,
                 points: torch.Tensor) -> torch.Tensor:
    """(N, 3) central-difference gradient of the interpolated SDF (step half a voxel)."""
    h = 0.5 * voxel_size_m
    offsets = torch.eye(3, dtype=points.dtype, device=points.device) * h
    probes = torch.cat([points[:, None, :] + offsets, points[:, None, :] - offsets], 1)
    d = sdf_lookup(values, origin, voxel_size_m, probes.reshape(-1, 3)).reshape(-1, 6)
    return (d[:, :3] - d[:, 3:]) / (2.0 * h)


def _select_lookup():
    """Prefer the project's shared ``r2s.geometry.sdf_torch.sdf_lookup`` when it exists."""
    try:
        from r2s.geometry.sdf_torch import sdf_lookup as shared  # type: ignore
    except ImportError:
        return trilinear_sdf
    return shared


_LOOKUP = _select_lookup()
