"""What changes during a rollout (Brax's ``State``) and how a rollout starts (``init``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
import torch

from r2s.sim.diffsim.rotation import (matrix_from_quat, quat_from_matrix, quat_from_rotvec,
                                      quat_multiply)
from r2s.sim.diffsim.system import System


@dataclass(frozen=True)
class State:
    """The free body's state.

    position : (3,) COM position, world frame, metres.
    orientation : (4,) unit quaternion (w, x, y, z), world_from_object rotation.
    linear_velocity : (3,) COM velocity, world frame, m/s.
    angular_velocity : (3,) world frame, rad/s.
    time_s : () simulated time.
    contact_impulse : (E, N, 3) last step's contact impulse per environment body (plane
        first, then obstacles) and sample point, world frame, N s; warm-starts the solver.
    """

    position: torch.Tensor
    orientation: torch.Tensor
    linear_velocity: torch.Tensor
    angular_velocity: torch.Tensor
    time_s: torch.Tensor
    contact_impulse: torch.Tensor


def environment_count(system: System) -> int:
    """Number of fixed environment bodies (plane first, then obstacles)."""
    return (1 if system.plane is not None else 0) + len(system.obstacles)


def init(system: System, world_from_object, linear_velocity=None, angular_velocity=None,
         translation: Optional[torch.Tensor] = None,
         rotvec: Optional[torch.Tensor] = None) -> State:
    """The state of a body placed at ``world_from_object``, optionally perturbed.

    Parameters
    ----------
    system : the model (its ``com_in_object`` places the COM, with gradient).
    world_from_object : (4, 4) pose (array-like or tensor).
    linear_velocity, angular_velocity : (3,) world frame; zero if None.
    translation : (3,) world-frame offset added to the pose (differentiable).
    rotvec : (3,) world-frame axis-angle applied on the left of the rotation (differentiable).
        The rotation is about the object's COM.

    Returns
    -------
    A :class:`State` at time 0 with zero warm-start impulses.
    """
    dtype, device = system.dtype, system.device
    pose = world_from_object
    if not isinstance(pose, torch.Tensor):
        pose = torch.as_tensor(np.asarray(pose, dtype=np.float64))
    pose = pose.to(dtype=dtype, device=device)
    rot, trans = pose[:3, :3], pose[:3, 3]
    quat = quat_from_matrix(rot)
    position = rot @ system.com_in_object + trans
    if rotvec is not None:
        quat = quat_multiply(quat_from_rotvec(rotvec.to(dtype)), quat)
    if translation is not None:
        position = position + translation.to(dtype)
    zeros = torch.zeros(3, dtype=dtype, device=device)
    v = zeros if linear_velocity is None else torch.as_tensor(linear_velocity, dtype=dtype,
                                                              device=device)
    w = zeros if angular_velocity is None else torch.as_tensor(angular_velocity, dtype=dtype,
                                                               device=device)
    impulse = torch.zeros(environment_count(system), system.points_in_object.shape[0], 3,
                          dtype=dtype, device=device)
    return State(position, quat, v, w, torch.zeros((), dtype=dtype, device=device), impulse)


def world_from_object(system: System, state: State) -> torch.Tensor:
    """(4, 4) object pose of ``state`` (differentiable)."""
    rot = matrix_from_quat(state.orientation)
    trans = state.position - rot @ system.com_in_object
    top = torch.cat([rot, trans[:, None]], 1)
    bottom = torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=rot.dtype, device=rot.device)
    return torch.cat([top, bottom], 0)


def points_in_world(system: System, state: State, rot: Optional[torch.Tensor] = None
                    ) -> tuple[torch.Tensor, torch.Tensor]:
    """World positions of the sample points and their lever arms from the COM.

    ``rot`` (3, 3) is the state's rotation matrix when the caller already has it.

    Returns
    -------
    points : (N, 3) world frame.
    lever_arms : (N, 3) ``points - COM`` (world frame axes), the ``p - c`` of the contact
        Jacobians.
    """
    if rot is None:
        rot = matrix_from_quat(state.orientation)
    lever = (system.points_in_object - system.com_in_object) @ rot.T
    return state.position + lever, lever
