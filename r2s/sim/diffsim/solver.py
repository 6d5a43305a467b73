"""Velocity-level contact impulses with Coulomb friction for one free body.

Problem (per step): find the body twist ``nu = (v, w)`` after contact and the contact
impulses ``lambda_k`` (contact frame: normal, tangent, tangent) such that

* momentum: ``M (nu - nu_free) = sum_k J_k^T lambda_k`` (``J_k`` maps the twist to the
  velocity of contact point k, whose lever arm from the COM is ``r_k = p_k - c``);
* non-penetration: ``lambda_n >= 0``, ``u_n >= target``, complementary, where
  ``u = J_k nu`` and ``target`` is the Baumgarte / speculative normal velocity;
* Coulomb friction: ``|lambda_t| <= mu lambda_n``; a sticking contact has ``u_t = 0``
  *exactly* (static friction is real: nothing creeps), a sliding one has
  ``lambda_t = -mu lambda_n u_t / |u_t|`` and does not lift off (``u_n = target``).

Forward solve (no autograd): a proximal-point (augmented Lagrangian) iteration on the
impulses with staggered friction, ``lambda <- P_C(lambda - rho (u(nu) - target))``, ``C`` the
set ``{lambda_n >= 0} x {|lambda_t| <= mu lambda_n_previous}``. For a fixed ``lambda`` and
``C`` the twist minimises the convex, once-differentiable function

    Phi(nu) = 1/2 |nu - nu_free|_M^2 + 1/rho sum_k e(lambda_k - rho (J_k nu - target_k)),
    e(x) = x . P_C(x) - 1/2 |P_C(x)|^2,

found by a semismooth Newton method in the six twist coordinates (one 6 x 6 solve per step,
every contact at once, Armijo line search on ``Phi``). Working in the twist rather than in
the impulses makes the solve indifferent to the number of contacts and to how degenerate
they are (a body whose COM sits near the edge of its support), where projected-gradient or
Jacobi iterations on the impulses need hundreds of iterations. ``rho`` is ``rho_scale`` over
the trace of ``J M^-1 J^T``. Iterations stop when the twist changes by less than
``tolerance_mps``; impulses are warm-started from the previous step, so a solve that hits
the iteration cap keeps converging over the next steps.

Gradients: the fixed point above is the Coulomb solution, which is also the fixed point of
De Saxce's form ``lambda <- P_K(lambda - rho sigma)``, ``K`` the friction cone and
``sigma = u - target + mu |u_t| e_n``. After the forward solve, ``refine_iterations`` such
iterations (a full semismooth Newton step on the twist, whose matrix includes the
derivative of the De Saxce shift, then the projection) run with autograd from the detached
solution: their value is the solution's and their derivative converges quickly to the
implicit derivative of the solution (checked against finite differences in the tests).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

@dataclass
class SolveStats:
    """Running counts of solves, outer iterations and Newton steps.

    Benchmark instrumentation only (``scripts/bench_diffsim.py`` reads and resets it); the
    simulator never reads it.
    """

    newton_steps: int = 0
    outer_iterations: int = 0
    solves: int = 0


STATS = SolveStats()


def contact_frames(normal: torch.Tensor) -> torch.Tensor:
    """(K, 3, 3) orthonormal frames whose rows are (n, t1, t2) for unit normals (K, 3).

    Branch-free construction of Duff et al. (2017), smooth except where ``n_z`` changes sign.
    """
    x, y, z = normal.unbind(-1)
    sign = torch.where(z >= 0, torch.ones_like(z), -torch.ones_like(z))
    a = -1.0 / (sign + z)
    b = x * y * a
    t1 = torch.stack([1.0 + sign * x * x * a, sign * b, -sign * x], -1)
    t2 = torch.stack([b, sign + y * y * a, -y], -1)
    return torch.stack([normal, t1, t2], -2)


def contact_jacobian(frames: torch.Tensor, lever: torch.Tensor) -> torch.Tensor:
    """(K, 3, 6) map from the body twist (v, w) to contact-frame point velocities.

    Row (k, j) is ``[e, r_k x e]`` for the frame axis ``e = frames[k, j]``, so that
    ``e . (v + w x r_k)`` is its product with ``(v, w)``.
    """
    angular = torch.linalg.cross(lever[:, None, :].expand_as(frames), frames)
    return torch.cat([frames, angular], -1)


def block_diag(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(6, 6) block-diagonal matrix of two (3, 3) blocks."""
    zero = torch.zeros_like(a)
    return torch.cat([torch.cat([a, zero], 1), torch.cat([zero, b], 1)], 0)


def delassus_bound(jacobian: torch.Tensor, inv_mass_matrix: torch.Tensor) -> torch.Tensor:
    """Upper bound of the largest eigenvalue of ``J M^-1 J^T`` (units 1/kg): its trace.

    Parameters
    ----------
    jacobian : (3K, 6) contact Jacobian.
    inv_mass_matrix : (6, 6) ``M^-1``.

    Returns
    -------
    () ``trace(J M^-1 J^T)``; at most 6 times the largest eigenvalue (rank <= 6).
    """
    return ((jacobian @ inv_mass_matrix) * jacobian).sum()


def project_cone(x: torch.Tensor, mu: torch.Tensor) -> torch.Tensor:
    """Euclidean projection of contact-frame vectors (K, 3) onto the cones ``K_mu`` (K,).

    ``K_mu = {(n, t): |t| <= mu n}``: inside stays, the polar cone goes to zero, the rest
    lands on the cone's surface.
    """
    x_n = x[:, 0]
    x_t = x[:, 1:]
    s = torch.sqrt((x_t * x_t).sum(-1) + 1e-30)
    p_n = (x_n + mu * s) / (1.0 + mu * mu)
    surface = torch.cat([p_n[:, None], (mu * p_n / s)[:, None] * x_t], 1)
    inside = (s <= mu * x_n)[:, None]
    polar = (mu * s <= -x_n)[:, None]
    return torch.where(inside, x, torch.where(polar, torch.zeros_like(x), surface))


def project_cone_jacobian(x: torch.Tensor, mu: torch.Tensor) -> torch.Tensor:
    """(K, 3, 3) symmetric derivative of :func:`project_cone` at ``x`` (K, 3)."""
    k = x.shape[0]
    x_n = x[:, 0]
    x_t = x[:, 1:]
    s = torch.sqrt((x_t * x_t).sum(-1) + 1e-30)
    t_hat = x_t / s[:, None]
    c = 1.0 / (1.0 + mu * mu)
    p_n = (x_n + mu * s) * c
    # On the surface: p = p_n (1, mu t_hat), p_n = c (x_n + mu s).
    e = torch.cat([torch.ones_like(s)[:, None], mu[:, None] * t_hat], 1)      # (K, 3)
    d = c[:, None, None] * e[:, :, None] * e[:, None, :]
    tangential = (mu * p_n / s)[:, None, None] * (
        torch.eye(2, dtype=x.dtype, device=x.device) - t_hat[:, :, None] * t_hat[:, None, :])
    d = d + torch.nn.functional.pad(tangential, (1, 0, 1, 0))
    inside = (s <= mu * x_n)[:, None, None]
    polar = (mu * s <= -x_n)[:, None, None]
    eye3 = torch.eye(3, dtype=x.dtype, device=x.device).expand(k, 3, 3)
    return torch.where(inside, eye3, torch.where(polar, torch.zeros_like(d), d))


def project_contact_set(x: torch.Tensor, radius: torch.Tensor) -> torch.Tensor:
    """Project contact-frame vectors (K, 3) onto ``{n >= 0} x {|t| <= radius}`` (radius (K,))."""
    x_t = x[:, 1:]
    length = torch.sqrt((x_t * x_t).sum(-1) + 1e-30)
    scale = torch.clamp(radius / length, max=1.0)
    return torch.cat([torch.relu(x[:, :1]), x_t * scale[:, None]], 1)


def project_contact_set_jacobian(x: torch.Tensor, radius: torch.Tensor) -> torch.Tensor:
    """(K, 3, 3) symmetric derivative of :func:`project_contact_set` at ``x`` (K, 3)."""
    x_t = x[:, 1:]
    length = torch.sqrt((x_t * x_t).sum(-1) + 1e-30)
    t_hat = x_t / length[:, None]
    eye2 = torch.eye(2, dtype=x.dtype, device=x.device)
    clipped = (radius / length)[:, None, None] * (eye2 - t_hat[:, :, None] * t_hat[:, None, :])
    d_t = torch.where((length <= radius)[:, None, None], eye2.expand_as(clipped), clipped)
    d_n = (x[:, 0] > 0).to(x.dtype)
    return torch.nn.functional.pad(d_t, (1, 0, 1, 0)) + torch.nn.functional.pad(
        d_n[:, None, None], (0, 2, 0, 2))


def _merit(nu, nu_free, mass_matrix, lam, rho, jac, target3, radius):
    """``Phi(nu)`` (see the module docstring), ``x = lam - rho (J nu - target)`` and ``P(x)``."""
    x = lam - rho * ((jac @ nu).reshape(-1, 3) - target3)
    p = project_contact_set(x, radius)
    dnu = nu - nu_free
    phi = 0.5 * dnu @ (mass_matrix @ dnu) + ((x - 0.5 * p) * p).sum() / rho
    return phi, x, p


def _newton_step(nu, nu_free, mass_matrix, rho, jac, jac3, x, p, radius):
    """Semismooth Newton step (6,) on ``Phi`` at ``nu`` and the gradient there (6,)."""
    grad = mass_matrix @ (nu - nu_free) - jac.T @ p.reshape(-1)
    d = project_contact_set_jacobian(x, radius)
    hess = mass_matrix + rho * (jac.T @ torch.bmm(d, jac3).reshape(-1, 6))
    return -torch.linalg.solve(hess, grad), grad


def _iterate(nu, nu_free, mass_matrix, lam, rho, jac, jac3, target3, mu,
             outer_iterations, newton_iterations, tolerance_mps):
    """Proximal-point iterations with line-searched Newton inner solves (no autograd use).

    Returns the twist (6,) and contact-frame impulses (K, 3).
    """
    for _ in range(outer_iterations):
        STATS.outer_iterations += 1
        nu_before = nu
        radius = mu * lam[:, 0]
        phi, x, p = _merit(nu, nu_free, mass_matrix, lam, rho, jac, target3, radius)
        small_step = False
        for _ in range(newton_iterations):
            STATS.newton_steps += 1
            step, grad = _newton_step(nu, nu_free, mass_matrix, rho, jac, jac3, x, p, radius)
            slope = float(grad @ step)
            if -slope <= float(mass_matrix[0, 0]) * tolerance_mps ** 2:
                small_step = True           # Newton decrement: |step| within the tolerance
                break
            alpha = 1.0
            while True:
                trial = _merit(nu + alpha * step, nu_free, mass_matrix, lam, rho, jac, target3,
                               radius)
                if float(trial[0] - phi) <= 1e-4 * alpha * slope or alpha < 1e-4:
                    break
                alpha *= 0.5
            nu = nu + alpha * step
            phi, x, p = trial
            small_step = float(step.abs().max()) * alpha < tolerance_mps
            if small_step:
                break
        lam = p
        if small_step and float((nu - nu_before).abs().max()) < tolerance_mps:
            break
    return nu, lam


def _desaxce_residual(nu, nu_free, mass_matrix, lam, rho, jac, target3, mu):
    """Momentum residual ``F(nu)`` (6,) of De Saxce's form and its intermediates.

    ``x = lam - rho (u - b(u))`` with ``u = J nu`` (K, 3) and ``b`` the target velocity less
    De Saxce's shift; ``p = P_K(x)`` are the impulses the twist ``nu`` implies, and
    ``F = M (nu - nu_free) - J^T p`` vanishes at the inner solution.
    """
    u = (jac @ nu).reshape(-1, 3)
    x = lam - rho * (u - _velocity_bias(target3, u, mu))
    p = project_cone(x, mu)
    return mass_matrix @ (nu - nu_free) - jac.T @ p.reshape(-1), u, x, p


def _desaxce_newton_step(residual, u, x, mass_matrix, rho, jac, jac3, mu,
                         sticking_speed_mps=1e-9):
    """Semismooth Newton step ``-F'(nu)^-1 F`` (6,) of :func:`_desaxce_residual`.

    ``F'`` includes the derivative of De Saxce's shift ``mu |u_t|`` (the normal row of each
    contact Jacobian gains ``mu t_hat^T J_t``), so that the derivative of a sliding contact
    is that of Coulomb's law; for a sticking contact ``t_hat`` is taken as
    ``u_t / max(|u_t|, 1e-9 m/s)``.
    """
    u_t = u[:, 1:]
    speed = torch.clamp(torch.sqrt((u_t * u_t).sum(-1) + 1e-30), min=sticking_speed_mps)
    t_hat = u_t / speed[:, None]
    normal_row = jac3[:, 0, :] + mu[:, None] * (t_hat[:, :, None] * jac3[:, 1:, :]).sum(1)
    jac_mod = torch.cat([normal_row[:, None, :], jac3[:, 1:, :]], 1)
    d = project_cone_jacobian(x, mu)
    derivative = mass_matrix + rho * (jac.T @ torch.bmm(d, jac_mod).reshape(-1, 6))
    return -torch.linalg.solve(derivative, residual)


def _velocity_bias(target3: torch.Tensor, u: torch.Tensor, mu: torch.Tensor) -> torch.Tensor:
    """(K, 3) target velocities less De Saxce's shift ``mu |u_t|`` of the contact velocity ``u``."""
    shift = mu * torch.sqrt((u[:, 1:] * u[:, 1:]).sum(-1) + 1e-30)
    return target3 - torch.nn.functional.pad(shift[:, None], (0, 2))


def _refine(nu, nu_free, mass_matrix, inv_mass_matrix, lam, rho, jac, jac3, target3, mu,
            iterations):
    """Differentiable De Saxce iterations from a detached solution ``nu`` (6,), ``lam`` (K, 3).

    Each takes the semismooth Newton step of :func:`_desaxce_newton_step` (halved while it
    does not reduce ``|F|``, which only happens away from a solution) and projects.
    """
    for _ in range(iterations):
        res, u, x, _ = _desaxce_residual(nu, nu_free, mass_matrix, lam, rho, jac, target3, mu)
        step = _desaxce_newton_step(res, u, x, mass_matrix, rho, jac, jac3, mu)
        norm = float((res @ (inv_mass_matrix @ res)).detach())
        alpha = 1.0
        for _ in range(10):
            trial = _desaxce_residual(nu + alpha * step, nu_free, mass_matrix, lam, rho, jac,
                                      target3, mu)[0]
            if float((trial @ (inv_mass_matrix @ trial)).detach()) <= norm:
                break
            alpha *= 0.5
        nu = nu + alpha * step
        lam = _desaxce_residual(nu, nu_free, mass_matrix, lam, rho, jac, target3, mu)[3]
    return nu, lam


def solve_impulses(v_free: torch.Tensor, w_free: torch.Tensor, mass: torch.Tensor,
                   inertia: torch.Tensor, inv_inertia: torch.Tensor, lever: torch.Tensor,
                   normal: torch.Tensor, target: torch.Tensor, mu: torch.Tensor,
                   warm_start: torch.Tensor, outer_iterations: int = 8,
                   newton_iterations: int = 8, tolerance_mps: float = 1e-6,
                   rho_scale: float = 1e4, refine_iterations: int = 2
                   ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Contact impulses and the resulting body velocity.

    The solve itself runs without autograd (see the module docstring); when any input
    requires grad it is followed by ``refine_iterations`` differentiable De Saxce
    iterations started at the detached solution. Their value is the solution's and their
    derivative approaches the implicit derivative of the solution geometrically (about
    1e-3 relative error per iteration left at the default ``rho_scale``).

    Parameters
    ----------
    v_free, w_free : (3,) body velocity before contact (gravity applied), world frame.
    mass : () kg.
    inertia, inv_inertia : (3, 3) world inertia about the COM and its inverse.
    lever : (K, 3) contact points minus COM, world frame.
    normal : (K, 3) unit contact normals (pointing into the free body's side).
    target : (K,) minimum normal velocity (m/s; negative lets a gap close).
    mu : (K,) Coulomb coefficients.
    warm_start : (K, 3) initial impulses, world frame (e.g. last step's).
    outer_iterations : most proximal-point updates of the impulses.
    newton_iterations : most Newton steps per outer iteration.
    tolerance_mps : stop when an outer iteration changes the twist by less than this (m/s,
        rad/s) and the last Newton step was below it.
    rho_scale : proximal weight ``rho`` times the trace of ``J M^-1 J^T``.
    refine_iterations : differentiable iterations after the solve (when grad is needed).

    Returns
    -------
    impulse : (K, 3) contact impulses, world frame, N s.
    v, w : (3,) body velocity after the contact impulses.
    """
    STATS.solves += 1
    frames = contact_frames(normal)
    jac3 = contact_jacobian(frames, lever)                                 # (K, 3, 6)
    jac = jac3.reshape(-1, 6)
    eye = torch.eye(3, dtype=mass.dtype, device=mass.device)
    mass_matrix = block_diag(mass * eye, inertia)
    inv_mass_matrix = block_diag(eye / mass, inv_inertia)
    nu_free = torch.cat([v_free, w_free])
    target3 = torch.nn.functional.pad(target[:, None], (0, 2))
    with torch.no_grad():
        rho = rho_scale / delassus_bound(jac, inv_mass_matrix)
        lam = torch.bmm(frames, warm_start[:, :, None])[:, :, 0]         # contact frame
        lam = torch.cat([torch.relu(lam[:, :1]), lam[:, 1:]], 1)
        nu0 = nu_free + inv_mass_matrix @ (jac.T @ lam.reshape(-1))
        nu, lam = _iterate(nu0, nu_free, mass_matrix, lam, rho, jac, jac3, target3, mu,
                           outer_iterations, newton_iterations, tolerance_mps)
    inputs = (v_free, w_free, mass, inertia, lever, normal, target, mu)
    if torch.is_grad_enabled() and any(t.requires_grad for t in inputs):
        nu, lam = _refine(nu, nu_free, mass_matrix, inv_mass_matrix, lam, rho, jac, jac3,
                          target3, mu, refine_iterations)
    impulse = torch.bmm(frames.transpose(1, 2), lam[:, :, None])[:, :, 0]
    return impulse, nu[:3], nu[3:]
