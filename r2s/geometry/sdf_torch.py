"""Differentiable signed distance lookups in torch: trilinear grids and analytic planes.

Gradients flow to the query points (not to the grid values). Outside a grid the distance
is the value at the closest grid point plus the Euclidean distance to that point, so the
function stays continuous, positive far away, and its gradient points back to the grid.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

_CORNERS = torch.tensor([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)],
                        dtype=torch.long)
"""(8, 3) corner offsets in C order, matching the (2, 2, 2) weight products below."""


@dataclass(frozen=True)
class PackedGrids:
    """Several cubic grids of possibly different resolutions in one flat tensor.

    flat : (sum R_m^3,) values, grid after grid, each in C order [i, j, k] = x, y, z.
    offsets : (M,) int64 start of each grid in ``flat``.
    resolutions : (M,) int64 R_m.
    origins : (M, 3) centre of voxel [0, 0, 0] of each grid, in its frame.
    voxel_sizes : (M,) voxel spacing.
    """

    flat: torch.Tensor
    offsets: torch.Tensor
    resolutions: torch.Tensor
    origins: torch.Tensor
    voxel_sizes: torch.Tensor


def pack_grids(values: list[torch.Tensor], origins: torch.Tensor, voxel_sizes: torch.Tensor
               ) -> PackedGrids:
    """Pack (R_m, R_m, R_m) grids with their (M, 3) origins and (M,) voxel sizes."""
    res = torch.as_tensor([v.shape[0] for v in values], dtype=torch.long)
    sizes = res ** 3
    offsets = torch.cumsum(sizes, 0) - sizes
    flat = torch.cat([v.reshape(-1) for v in values]) if values else torch.zeros(0)
    return PackedGrids(flat, offsets, res, torch.as_tensor(origins), torch.as_tensor(voxel_sizes))


def sdf_lookup_packed(grids: PackedGrids, grid_index: torch.Tensor, points: torch.Tensor
                      ) -> torch.Tensor:
    """Signed distance of each of (N, 3) points in its grid ``grid_index`` (N,); (N,).

    Points are in their grid's frame; the result is differentiable w.r.t. ``points``.
    """
    dtype = points.dtype
    r = grids.resolutions[grid_index]  # (N,)
    top = (r - 1).to(dtype)[:, None]
    origin = grids.origins.to(dtype)[grid_index]
    voxel = grids.voxel_sizes.to(dtype)[grid_index].unsqueeze(-1)
    u = (points - origin) / voxel
    uc = torch.minimum(u.clamp_min(0.0), top)
    i0 = torch.minimum(torch.floor(uc.detach()).long(), (r - 2)[:, None]).clamp_min(0)
    t = uc - i0.to(dtype)
    idx = i0[:, None, :] + _CORNERS.to(points.device)[None]  # (N, 8, 3)
    rr = r[:, None]
    lin = grids.offsets[grid_index][:, None] + (idx[..., 0] * rr + idx[..., 1]) * rr + idx[..., 2]
    corner_values = grids.flat[lin].to(dtype)  # (N, 8)
    w = torch.stack([1.0 - t, t], dim=-1)  # (N, 3, 2): weights of the lower/upper corner
    weights = (w[:, 0, :, None, None] * w[:, 1, None, :, None] * w[:, 2, None, None, :]).reshape(-1, 8)
    out = (weights * corner_values).sum(dim=-1)
    offset = (u - uc) * voxel
    sq = (offset * offset).sum(dim=-1)
    outside = torch.sqrt(sq.clamp_min(1e-30)) * (sq > 0).to(dtype)
    return out + outside


def sdf_lookup_batched(values: torch.Tensor, origins: torch.Tensor, voxel_sizes: torch.Tensor,
                       grid_index: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Signed distance of each point in its own grid, for M grids of one resolution.

    Parameters
    ----------
    values : (M, R, R, R) signed distances at voxel centres, [m, i, j, k] = grid m, x, y, z.
    origins : (M, 3) position of voxel [0, 0, 0]'s centre, in each grid's frame.
    voxel_sizes : (M,) voxel spacing.
    grid_index : (N,) int64, which grid each point is looked up in.
    points : (N, 3) query points, each in its grid's frame.

    Returns
    -------
    (N,) signed distances, differentiable with respect to ``points``.
    """
    m, r = values.shape[0], values.shape[1]
    res = torch.full((m,), r, dtype=torch.long)
    packed = PackedGrids(values.reshape(-1), torch.arange(m, dtype=torch.long) * r**3, res,
                         torch.as_tensor(origins), torch.as_tensor(voxel_sizes))
    return sdf_lookup_packed(packed, grid_index, points)


def sdf_lookup(values: torch.Tensor, origin: torch.Tensor, voxel_size: float | torch.Tensor,
               points: torch.Tensor) -> torch.Tensor:
    """Trilinear signed distance of (N, 3) points in one (R, R, R) grid; (N,).

    ``origin`` (3,) is the centre of voxel [0, 0, 0]; points are in the grid's frame.
    """
    voxel = torch.as_tensor(voxel_size, dtype=points.dtype).reshape(1)
    idx = torch.zeros(points.shape[0], dtype=torch.long, device=points.device)
    return sdf_lookup_batched(values.unsqueeze(0), torch.as_tensor(origin).reshape(1, 3),
                              voxel, idx, points)


def plane_sdf(points: torch.Tensor, point: torch.Tensor, normal: torch.Tensor) -> torch.Tensor:
    """Signed distance of (N, 3) points to the plane through ``point`` with ``normal``.

    Positive on the side the normal points to (above a support plane); (N,).
    """
    n = normal.to(points.dtype)
    n = n / torch.linalg.norm(n)
    return (points - point.to(points.dtype)) @ n
