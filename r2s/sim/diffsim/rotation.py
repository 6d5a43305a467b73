"""Differentiable rotation helpers in torch (quaternions are ``(w, x, y, z)``, unit).

Every function works on a single rotation or on a batch (leading dimensions) and is safe
to differentiate at the identity / zero angle (no NaN gradient): norms are taken with a
small epsilon and the small-angle branches use Taylor expansions selected with
``torch.where`` on inputs that are themselves finite.
"""

from __future__ import annotations

import torch

EPS = 1e-12


def safe_norm(x: torch.Tensor, dim: int = -1, keepdim: bool = False,
              eps: float = EPS) -> torch.Tensor:
    """``sqrt(|x|^2 + eps^2)``: a norm whose gradient is finite at ``x = 0``."""
    return torch.sqrt((x * x).sum(dim=dim, keepdim=keepdim) + eps * eps)


def skew(v: torch.Tensor) -> torch.Tensor:
    """(..., 3) -> (..., 3, 3) cross-product matrix: ``skew(a) @ b = a x b``."""
    zero = torch.zeros_like(v[..., 0])
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    rows = [torch.stack([zero, -z, y], -1), torch.stack([z, zero, -x], -1),
            torch.stack([-y, x, zero], -1)]
    return torch.stack(rows, -2)


def quat_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product ``a * b`` of (..., 4) quaternions (w, x, y, z)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], -1)


def quat_normalize(q: torch.Tensor) -> torch.Tensor:
    """(..., 4) unit quaternion (safe at zero)."""
    return q / safe_norm(q, keepdim=True)


def quat_from_rotvec(rotvec: torch.Tensor) -> torch.Tensor:
    """(..., 3) axis-angle (radians, axis * angle) -> (..., 4) unit quaternion (w, x, y, z)."""
    theta_sq = (rotvec * rotvec).sum(-1, keepdim=True)
    small = theta_sq < 1e-8
    theta = torch.sqrt(torch.where(small, torch.ones_like(theta_sq), theta_sq))
    half = 0.5 * theta
    # sin(theta/2)/theta and cos(theta/2), Taylor near zero.
    sinc_half = torch.where(small, 0.5 - theta_sq / 48.0, torch.sin(half) / theta)
    cos_half = torch.where(small, 1.0 - theta_sq / 8.0, torch.cos(half))
    return torch.cat([cos_half, sinc_half * rotvec], -1)


def matrix_from_quat(q: torch.Tensor) -> torch.Tensor:
    """(..., 4) quaternion (w, x, y, z), normalised first -> (..., 3, 3) rotation matrix."""
    q = quat_normalize(q)
    w, x, y, z = q.unbind(-1)
    rows = [
        torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ]
    return torch.stack(rows, -2)


def quat_from_matrix(rot: torch.Tensor) -> torch.Tensor:
    """(3, 3) rotation matrix -> (4,) unit quaternion (w, x, y, z) with w >= 0.

    Shepperd's method: the branch with the largest diagonal term is used, so the square
    root is always taken of a number >= 1 (finite gradients).
    """
    m = rot
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    candidates = torch.stack([trace, m[0, 0], m[1, 1], m[2, 2]])
    k = int(torch.argmax(candidates.detach()))
    if k == 0:
        s = torch.sqrt(1.0 + trace) * 2.0
        q = torch.stack([0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s,
                         (m[1, 0] - m[0, 1]) / s])
    elif k == 1:
        s = torch.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2.0
        q = torch.stack([(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s,
                         (m[0, 2] + m[2, 0]) / s])
    elif k == 2:
        s = torch.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2.0
        q = torch.stack([(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s,
                         (m[1, 2] + m[2, 1]) / s])
    else:
        s = torch.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2.0
        q = torch.stack([(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s,
                         (m[1, 2] + m[2, 1]) / s, 0.25 * s])
    q = torch.where(q[0] < 0, -q, q)
    return quat_normalize(q)


def integrate_quat(q: torch.Tensor, angular_velocity: torch.Tensor, dt: float) -> torch.Tensor:
    """Rotate ``q`` by a world-frame angular velocity (rad/s) held for ``dt`` seconds.

    ``q_next = exp(angular_velocity * dt) * q`` (exact exponential map), renormalised.
    """
    return quat_normalize(quat_multiply(quat_from_rotvec(angular_velocity * dt), q))
