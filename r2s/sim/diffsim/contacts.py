"""Contact candidates: signed distance, normal and friction of every sample point against
every fixed environment body (plane first, then the SDF obstacles)."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from r2s.sim.diffsim.rotation import safe_norm
from r2s.sim.diffsim.sdf import sdf_gradient, sdf_lookup
from r2s.sim.diffsim.system import SdfObstacle, SupportPlane, System


@dataclass(frozen=True)
class Contacts:
    """Per environment body e and sample point i (all world frame).

    distance : (E, N) signed distance of the point to body e, metres (negative = inside).
    normal : (E, N, 3) unit normal of body e at the point, pointing out of body e.
    friction : (E,) Coulomb coefficient, product of the body's and e's friction values.
    active : (E, N) float mask, 1 where ``distance < contact_margin_m``.
    """

    distance: torch.Tensor
    normal: torch.Tensor
    friction: torch.Tensor
    active: torch.Tensor


def plane_distance(plane: SupportPlane, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(N,) signed distances and (N, 3) normals of ``points`` (N, 3) to a support plane."""
    distance = (points - plane.point) @ plane.normal
    return distance, plane.normal.expand_as(points)


def obstacle_distance(obstacle: SdfObstacle, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(N,) signed distances and (N, 3) world normals of world ``points`` to an SDF obstacle."""
    rot = obstacle.world_from_object[:3, :3]
    local = (points - obstacle.world_from_object[:3, 3]) @ rot
    distance = sdf_lookup(obstacle.values, obstacle.origin, obstacle.voxel_size_m, local)
    grad = sdf_gradient(obstacle.values, obstacle.origin, obstacle.voxel_size_m, local)
    normal = (grad / safe_norm(grad, keepdim=True)) @ rot.T
    return distance, normal


def find_contacts(system: System, points: torch.Tensor) -> Contacts:
    """:class:`Contacts` of the world sample ``points`` (N, 3) against the environment."""
    distances, normals, frictions = [], [], []
    if system.plane is not None:
        d, n = plane_distance(system.plane, points)
        distances.append(d)
        normals.append(n)
        frictions.append(system.friction * system.plane.friction)
    for obstacle in system.obstacles:
        d, n = obstacle_distance(obstacle, points)
        distances.append(d)
        normals.append(n)
        frictions.append(system.friction * obstacle.friction)
    if not distances:
        empty = points.new_zeros((0, points.shape[0]))
        return Contacts(empty, points.new_zeros((0, points.shape[0], 3)), points.new_zeros(0), empty)
    distance = torch.stack(distances)
    active = (distance.detach() < system.params.contact_margin_m).to(points.dtype)
    return Contacts(distance, torch.stack(normals), torch.stack(frictions), active)
