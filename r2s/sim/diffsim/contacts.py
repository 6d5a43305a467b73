"""Contacts: the (environment body, sample point) pairs closer than the contact margin.

Environment bodies are numbered plane first (when there is one), then the SDF obstacles in
``system.obstacles`` order. Only the pairs whose signed distance is below
``system.params.contact_margin_m`` are kept; their distance, normal and friction are
differentiable w.r.t. the point positions (hence the body pose and COM) and the frictions.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from r2s.sim.diffsim.rotation import safe_norm
from r2s.sim.diffsim.sdf import sdf_gradient, sdf_lookup
from r2s.sim.diffsim.system import SdfObstacle, SupportPlane, System


@dataclass(frozen=True)
class Contacts:
    """K contact pairs (world frame).

    body : (K,) long, index of the environment body.
    point : (K,) long, index of the body's sample point.
    distance : (K,) signed distance of the point to the environment body, metres.
    normal : (K, 3) unit normal of the environment body, pointing out of it.
    friction : (K,) Coulomb coefficient (product of the two friction values).
    """

    body: torch.Tensor
    point: torch.Tensor
    distance: torch.Tensor
    normal: torch.Tensor
    friction: torch.Tensor

    @property
    def count(self) -> int:
        return int(self.point.shape[0])


def plane_distance(plane: SupportPlane, points: torch.Tensor) -> torch.Tensor:
    """(N,) signed distances of world ``points`` (N, 3) to a support plane."""
    return (points - plane.point) @ plane.normal


def obstacle_local(obstacle: SdfObstacle, points: torch.Tensor) -> torch.Tensor:
    """(N, 3) world ``points`` in the obstacle's object frame."""
    rot = obstacle.world_from_object[:3, :3]
    return (points - obstacle.world_from_object[:3, 3]) @ rot


def near_grid(obstacle: SdfObstacle, local: torch.Tensor, margin_m: float) -> torch.Tensor:
    """(M,) long indices of object-frame points (N, 3) within ``margin_m`` of the grid box.

    Points farther away are farther than ``margin_m`` from the obstacle (the grid box
    contains it), so their look-up can be skipped.
    """
    size = torch.tensor(obstacle.values.shape, dtype=local.dtype, device=local.device)
    lower = obstacle.origin.detach() - margin_m
    upper = obstacle.origin.detach() + (size - 1) * obstacle.voxel_size_m + margin_m
    inside = ((local > lower) & (local < upper)).all(-1)
    return torch.nonzero(inside).reshape(-1)


def obstacle_normal(obstacle: SdfObstacle, points: torch.Tensor) -> torch.Tensor:
    """(N, 3) world unit normals (normalised SDF gradient) at world ``points`` (N, 3)."""
    local = obstacle_local(obstacle, points)
    grad = sdf_gradient(obstacle.values, obstacle.origin, obstacle.voxel_size_m, local)
    return (grad / safe_norm(grad, keepdim=True)) @ obstacle.world_from_object[:3, :3].T


def find_contacts(system: System, points: torch.Tensor, margin_m: float | None = None) -> Contacts:
    """The :class:`Contacts` of world sample ``points`` (N, 3) closer than ``margin_m``.

    ``margin_m`` defaults to ``system.params.contact_margin_m``.
    """
    margin = system.params.contact_margin_m if margin_m is None else margin_m
    bodies, idx, dists, normals, frictions = [], [], [], [], []
    index = 0
    if system.plane is not None:
        d = plane_distance(system.plane, points)
        keep = torch.nonzero(d.detach() < margin).reshape(-1)
        bodies.append(torch.full_like(keep, index))
        idx.append(keep)
        dists.append(d[keep])
        normals.append(system.plane.normal.expand(keep.shape[0], 3))
        frictions.append((system.friction * system.plane.friction).expand(keep.shape[0]))
        index += 1
    for obstacle in system.obstacles:
        local = obstacle_local(obstacle, points)
        near = near_grid(obstacle, local.detach(), margin)
        d = sdf_lookup(obstacle.values, obstacle.origin, obstacle.voxel_size_m, local[near])
        close = torch.nonzero(d.detach() < margin).reshape(-1)
        keep = near[close]
        bodies.append(torch.full_like(keep, index))
        idx.append(keep)
        dists.append(d[close])
        normals.append(obstacle_normal(obstacle, points[keep]))
        frictions.append((system.friction * obstacle.friction).expand(keep.shape[0]))
        index += 1
    if not bodies:
        empty = torch.zeros(0, dtype=torch.long, device=points.device)
        return Contacts(empty, empty, points.new_zeros(0), points.new_zeros(0, 3),
                        points.new_zeros(0))
    return Contacts(torch.cat(bodies), torch.cat(idx), torch.cat(dists), torch.cat(normals),
                    torch.cat(frictions))
