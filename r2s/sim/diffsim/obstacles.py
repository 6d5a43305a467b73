"""Fixed obstacles as :class:`SdfObstacle`: from an :class:`SdfGrid`, a mesh, or an exact box."""

from __future__ import annotations

import numpy as np
import torch
import trimesh

from r2s.geometry.sdf import SdfGrid, compute_sdf, grid_layout, grid_points
from r2s.sim.diffsim.system import SdfObstacle, make_obstacle


def obstacle_from_grid(grid: SdfGrid, world_from_object, friction: float,
                       dtype=torch.float64, device=None) -> SdfObstacle:
    """A fixed body from a signed distance grid (object frame) placed at ``world_from_object``."""
    return make_obstacle(grid.values_m, grid.origin_m, grid.voxel_size_m, world_from_object,
                         friction, dtype, device)


def mesh_obstacle(mesh: trimesh.Trimesh, world_from_object, friction: float,
                  resolution: int = 64, dtype=torch.float64, device=None) -> SdfObstacle:
    """A fixed mesh (object frame) as a ``resolution``^3 SDF grid (:func:`compute_sdf`)."""
    return obstacle_from_grid(compute_sdf(mesh, resolution), world_from_object, friction,
                              dtype, device)


def box_sdf(half_extents, points: np.ndarray) -> np.ndarray:
    """Exact signed distance of ``points`` (..., 3) to a centred box (negative inside)."""
    q = np.abs(points) - np.asarray(half_extents, dtype=np.float64)
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
    inside = np.minimum(q.max(-1), 0.0)
    return outside + inside


def box_obstacle(half_extents, world_from_object, friction: float, resolution: int = 64,
                 padding_m: float = 0.02, dtype=torch.float64, device=None) -> SdfObstacle:
    """A fixed box centred at its object origin, its exact SDF sampled on a cubic grid."""
    half = np.asarray(half_extents, dtype=np.float64)
    origin, voxel = grid_layout(np.stack([-half, half]), resolution, padding_m)
    values = box_sdf(half, grid_points(origin, voxel, resolution))
    return make_obstacle(values, origin, voxel, world_from_object, friction, dtype, device)
