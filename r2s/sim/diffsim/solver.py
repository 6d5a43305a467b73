"""Velocity-level contact impulses with Coulomb friction for one free body.

Problem (per step): find contact impulses ``P_k`` (K, 3), world frame, such that the body's
post-step velocity ``(v, w) = (v*, w*) + M^-1 J^T P`` satisfies, for every active contact k
with normal ``n_k``, lever arm ``r_k`` (from the COM) and point velocity
``u_k = v + w x r_k``:

* normal: ``lambda_k = P_k . n_k >= 0``, ``u_k . n_k >= target_k``, complementary;
* friction: the tangential impulse ``P_k - lambda_k n_k`` lies in the disk of radius
  ``mu_k lambda_k`` and opposes the tangential velocity; it drives that velocity to exactly
  zero whenever the disk allows it (true static friction: nothing creeps).

Solved with accelerated projected gradient iterations on the impulses (Nesterov momentum
with adaptive restart), every contact at once: each iteration is a handful of vectorised
tensor operations over the K contacts, and the fixed iteration count keeps the whole solve
differentiable by ordinary autograd. The step size is ``1 / L`` with ``L`` a smooth upper
bound of the largest eigenvalue of the Delassus operator ``J M^-1 J^T`` (computed from the
6 x 6 matrix with the same non-zero spectrum). The friction radius uses the current normal
impulse (the staggered treatment of Bullet / ODE), so a sliding body does not lift off.
"""

from __future__ import annotations

import torch

from r2s.sim.diffsim.rotation import safe_norm, skew


def delassus_bound(lever: torch.Tensor, active: torch.Tensor, inv_mass: torch.Tensor,
                   inv_inertia: torch.Tensor) -> torch.Tensor:
    """Smooth upper bound of the largest eigenvalue of ``J M^-1 J^T``.

    Parameters
    ----------
    lever : (K, 3) lever arms ``p - c``, world frame.
    active : (K,) 0/1 weights of the contacts taking part.
    inv_mass : () 1 / mass.
    inv_inertia : (3, 3) inverse world inertia about the COM.

    Returns
    -------
    () ``||B^4||_F^(1/4)`` where ``B = C^T (sum_k G_k^T G_k) C``, ``G_k = [I, -skew(r_k)]``,
    ``C C^T = M^-1``; within a factor 6^(1/8) of the exact value.
    """
    dtype, device = lever.dtype, lever.device
    count = active.sum()
    moment = (active[:, None] * lever).sum(0)
    sk = skew(lever)
    rot_block = -(active[:, None, None] * (sk @ sk)).sum(0)
    eye = torch.eye(3, dtype=dtype, device=device)
    s = torch.cat([torch.cat([count * eye, -skew(moment)], 1),
                   torch.cat([skew(moment), rot_block], 1)], 0)
    chol_rot = torch.linalg.cholesky(inv_inertia)
    zero = torch.zeros(3, 3, dtype=dtype, device=device)
    c = torch.cat([torch.cat([torch.sqrt(inv_mass) * eye, zero], 1),
                   torch.cat([zero, chol_rot], 1)], 0)
    b = c.T @ s @ c
    b2 = b @ b
    b4 = b2 @ b2
    return torch.sqrt(torch.sqrt(torch.sqrt((b4 * b4).sum() + 1e-30)))


def body_velocity(impulse: torch.Tensor, lever: torch.Tensor, v_free: torch.Tensor,
                  w_free: torch.Tensor, inv_mass: torch.Tensor,
                  inv_inertia: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Body velocity (3,), (3,) after applying contact ``impulse`` (K, 3) at ``lever`` (K, 3)."""
    v = v_free + inv_mass * impulse.sum(0)
    w = w_free + inv_inertia @ torch.linalg.cross(lever, impulse).sum(0)
    return v, w


def project_disk(x: torch.Tensor, radius: torch.Tensor) -> torch.Tensor:
    """(K, 3) vectors clipped to length ``radius`` (K,) (radius >= 0)."""
    length = safe_norm(x)
    scale = radius / torch.clamp(torch.maximum(length, radius), min=1e-30)
    return x * scale[:, None]


def solve_impulses(v_free: torch.Tensor, w_free: torch.Tensor, inv_mass: torch.Tensor,
                   inv_inertia: torch.Tensor, lever: torch.Tensor, normal: torch.Tensor,
                   target: torch.Tensor, mu: torch.Tensor, active: torch.Tensor,
                   warm_start: torch.Tensor, iterations: int
                   ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Contact impulses and the resulting body velocity.

    Parameters
    ----------
    v_free, w_free : (3,) body velocity before contact (gravity applied), world frame.
    inv_mass : () 1 / mass.
    inv_inertia : (3, 3) inverse world inertia about the COM.
    lever : (K, 3) contact points minus COM, world frame.
    normal : (K, 3) unit contact normals (pointing into the free body's side).
    target : (K,) minimum normal velocity (m/s; negative lets a gap close).
    mu : (K,) Coulomb coefficients.
    active : (K,) 0/1 contact mask (inactive contacts carry no impulse).
    warm_start : (K, 3) initial impulses (e.g. last step's).
    iterations : number of accelerated projected-gradient iterations.

    Returns
    -------
    impulse : (K, 3) contact impulses, world frame, N s.
    v, w : (3,) body velocity after the contact impulses.
    """
    step = 1.0 / delassus_bound(lever, active, inv_mass, inv_inertia)
    x = warm_start * active[:, None]
    y = x
    t = torch.ones((), dtype=x.dtype, device=x.device)
    for _ in range(iterations):
        v, w = body_velocity(y, lever, v_free, w_free, inv_mass, inv_inertia)
        u = v + torch.linalg.cross(w.expand_as(lever), lever)
        u_n = (u * normal).sum(-1)
        u_t = u - u_n[:, None] * normal
        y_n = (y * normal).sum(-1)
        y_t = y - y_n[:, None] * normal
        lam_n = torch.relu(y_n - step * (u_n - target)) * active
        lam_t = project_disk(y_t - step * u_t, mu * lam_n)
        x_next = lam_n[:, None] * normal + lam_t
        # Nesterov momentum with gradient-based adaptive restart (O'Donoghue & Candes).
        restart = ((y - x_next) * (x_next - x)).sum() > 0
        t_next = 0.5 * (1.0 + torch.sqrt(1.0 + 4.0 * t * t))
        t_next = torch.where(restart, torch.ones_like(t_next), t_next)
        momentum = torch.where(restart, torch.zeros_like(t), (t - 1.0) / t_next)
        y = x_next + momentum * (x_next - x)
        x, t = x_next, t_next
    v, w = body_velocity(x, lever, v_free, w_free, inv_mass, inv_inertia)
    return x, v, w
