"""Differentiable look-up of a signed distance grid (trilinear), for the simulator's obstacles.

Grid convention (the project's, :class:`r2s.geometry.sdf.SdfGrid`): ``values[i, j, k]`` is
the signed distance (metres, negative inside) at the voxel centre
``origin + voxel_size_m * (i, j, k)`` in the obstacle's object frame. A point outside the
grid box is clamped onto it and the clamping distance is added, so far points read a
positive distance that grows with the distance to the grid.

Cubic grids go through the project's shared :func:`r2s.geometry.sdf_torch.sdf_lookup`
(same convention); :func:`trilinear_sdf` is this package's own version, used for
non-cubic grids. The two agree to rounding.
"""

from __future__ import annotations

import torch

from r2s.geometry.sdf_torch import sdf_lookup as cubic_sdf_lookup
from r2s.sim.diffsim.rotation import safe_norm

_CORNERS = torch.tensor([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])


def trilinear_sdf(values: torch.Tensor, origin: torch.Tensor, voxel_size_m: float,
                  points: torch.Tensor) -> torch.Tensor:
    """Signed distance at ``points`` by trilinear interpolation of ``values``.

    Parameters
    ----------
    values : (X, Y, Z) signed distances at the voxel centres, metres.
    origin : (3,) position of voxel [0, 0, 0]'s centre, same frame as ``points``.
    voxel_size_m : spacing of the voxel centres.
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
    _, ny, nz = values.shape
    corners = _CORNERS.to(device=points.device)
    node = base[:, None, :] + corners                                # (N, 8, 3)
    flat_index = (node[..., 0] * ny + node[..., 1]) * nz + node[..., 2]
    weight = torch.where(corners.bool(), frac[:, None, :], 1.0 - frac[:, None, :]).prod(-1)
    out = (weight * values.reshape(-1)[flat_index]).sum(-1)
    return out + outside


def sdf_lookup(values: torch.Tensor, origin: torch.Tensor, voxel_size_m: float,
               points: torch.Tensor) -> torch.Tensor:
    """(N,) trilinear signed distance at ``points`` (N, 3); see the module docstring."""
    cubic = values.shape[0] == values.shape[1] == values.shape[2]
    if cubic:
        return cubic_sdf_lookup(values, origin, voxel_size_m, points)
    return trilinear_sdf(values, origin, voxel_size_m, points)


def sdf_gradient(values: torch.Tensor, origin: torch.Tensor, voxel_size_m: float,
                 points: torch.Tensor) -> torch.Tensor:
    """(N, 3) central-difference gradient of the interpolated SDF (step half a voxel)."""
    h = 0.5 * voxel_size_m
    offsets = torch.eye(3, dtype=points.dtype, device=points.device) * h
    probes = torch.cat([points[:, None, :] + offsets, points[:, None, :] - offsets], 1)
    d = sdf_lookup(values, origin, voxel_size_m, probes.reshape(-1, 3)).reshape(-1, 6)
    return (d[:, :3] - d[:, 3:]) / (2.0 * h)

