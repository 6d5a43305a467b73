"""Stability losses for the physics-constrained optimisation (pure functions).

* :func:`sim_velocity_loss` is the paper's ``L_sim``: the time-integrated squared speed of
  a short rollout from the pose being optimised (zero when the body stays at rest).
* :func:`static_wrench_residual` asks the quasi-static question directly: can contact
  forces at the pose's contacts (non-negative normal parts, friction inside the Coulomb
  cone) balance gravity? Its residual is zero when they can and grows as the COM leaves the
  support polygon or the friction cone is exceeded; it has gradients w.r.t. the pose, the
  COM and the friction.
"""

from __future__ import annotations

import math
from typing import Optional, Sequence

import torch

from r2s.sim.diffsim.contacts import find_contacts
from r2s.sim.diffsim.solver import contact_frames, contact_jacobian, project_cone
from r2s.sim.diffsim.state import State, points_in_world
from r2s.sim.diffsim.system import System


def sim_velocity_loss(states: Sequence[State], dt_s: float,
                      length_scale_m: float = 0.1) -> torch.Tensor:
    """``1/2 sum_t (|v_t|^2 + length_scale^2 |w_t|^2) dt`` over ``states[1:]``.

    Parameters
    ----------
    states : a rollout (the first state, the initial one, is not counted).
    dt_s : time step of the rollout.
    length_scale_m : converts angular speed (rad/s) into a point speed (m/s); about the
        body's radius.

    Returns
    -------
    () loss in m^2/s.
    """
    total = states[0].linear_velocity.new_zeros(())
    for s in states[1:]:
        total = total + (s.linear_velocity.square().sum()
                         + length_scale_m ** 2 * s.angular_velocity.square().sum())
    return 0.5 * dt_s * total


def _spectral_bound(matrix: torch.Tensor) -> torch.Tensor:
    """Smooth upper bound ``||A^4||_F^(1/4)`` of the largest eigenvalue of a PSD (6, 6) ``A``."""
    a2 = matrix @ matrix
    a4 = a2 @ a2
    return torch.sqrt(torch.sqrt(torch.sqrt((a4 * a4).sum() + 1e-30)))


def static_wrench_residual(system: System, state: State, margin_m: Optional[float] = None,
                           iterations: int = 200, length_scale_m: Optional[float] = None
                           ) -> tuple[torch.Tensor, torch.Tensor]:
    """How far the best admissible contact forces are from balancing gravity.

    Solves ``min_f |D (J^T f + w_g)|^2 / (m |g|)^2`` over contact-frame forces ``f`` (K, 3)
    in the Coulomb cones (accelerated projected gradient with restart, a fixed number of
    iterations, differentiable), where ``J^T f`` is the wrench (force, torque about the
    COM) of the contact forces, ``w_g = (m g, 0)`` gravity's and
    ``D = diag(1, 1, 1, 1/l, 1/l, 1/l)``.

    Parameters
    ----------
    system, state : the body and its pose (velocities are ignored).
    margin_m : sample points closer than this to the environment may carry force
        (default ``system.params.contact_margin_m``); a body floating less than this above
        its support counts as supported, so pass a small margin to be strict.
    iterations : solver iterations.
    length_scale_m : ``l``, converting torque to force; default the RMS distance of the
        sample points from the COM.

    Returns
    -------
    residual : () dimensionless, 0 when gravity can be balanced, 1 with no contact.
    forces : (K, 3) world-frame contact forces in N (K = number of contacts).
    """
    points, lever = points_in_world(system, state)
    contacts = find_contacts(system, points, margin_m)
    weight = system.mass_kg * torch.linalg.norm(system.gravity)
    if contacts.count == 0:
        return torch.ones_like(weight), points.new_zeros(0, 3)
    if length_scale_m is None:
        length_scale_m = float(torch.sqrt(lever.detach().square().sum(-1).mean()))
    frames = contact_frames(contacts.normal)
    jac = contact_jacobian(frames, lever[contacts.point]).reshape(-1, 6)   # (3K, 6)
    scale = torch.tensor([1.0] * 3 + [1.0 / length_scale_m] * 3, dtype=jac.dtype, device=jac.device)
    jac_s = jac * scale                                            # rows of J D
    gravity_s = torch.cat([system.gravity / torch.linalg.norm(system.gravity),
                           system.gravity.new_zeros(3)])            # unit weight, no torque
    step = 1.0 / _spectral_bound(jac_s.T @ jac_s)
    k = contacts.count
    x = torch.cat([torch.full((k, 1), 1.0 / k, dtype=jac.dtype, device=jac.device),
                   jac.new_zeros(k, 2)], 1)                        # forces / (m |g|)
    y, t = x, 1.0
    for _ in range(iterations):
        wrench = jac_s.T @ y.reshape(-1) + gravity_s
        x_next = project_cone(y - step * (jac_s @ wrench).reshape(-1, 3), contacts.friction)
        if float(((y - x_next) * (x_next - x)).sum().detach()) > 0.0:
            t_next, momentum = 1.0, 0.0
        else:
            t_next = 0.5 * (1.0 + math.sqrt(1.0 + 4.0 * t * t))
            momentum = (t - 1.0) / t_next
        y = x_next + momentum * (x_next - x) if momentum else x_next
        x, t = x_next, t_next
    wrench = jac_s.T @ x.reshape(-1) + gravity_s
    forces = torch.einsum("kij,ki->kj", frames, x) * weight
    return (wrench * wrench).sum(), forces
