"""The image-space anchor: moves across the viewing ray cost more than along it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from r2s.geomopt.losses import anchor_term

SIGMA_T, SIGMA_R = 0.02, 0.01


def _grad(trans: np.ndarray, ray: np.ndarray, ratio: float) -> np.ndarray:
    t = torch.tensor(trans[None], dtype=torch.float64, requires_grad=True)
    rays = torch.tensor(ray[None], dtype=torch.float64)
    anchor_term(torch.zeros_like(t), t, SIGMA_R, SIGMA_T, rays, ratio).sum().backward()
    return t.grad[0].numpy()


@pytest.mark.parametrize("ratio", [1.0, 3.0, 5.0])
def test_gradient_zero_at_observed_pose_and_ratio_across_vs_along(ratio: float):
    # oblique viewing ray (camera 45 deg above the table looking down at the object)
    ray = np.array([0.0, np.sqrt(0.5), -np.sqrt(0.5)])
    side = np.array([1.0, 0.0, 0.0])  # across the ray
    assert np.abs(_grad(np.zeros(3), ray, ratio)).max() == 0.0
    eps = 1e-3
    g_along = _grad(eps * ray, ray, ratio)
    g_side = _grad(eps * side, ray, ratio)
    # analytic: d/dt (t_along^2 / s^2 + ratio^2 t_perp^2 / s^2) = 2 t / s^2 (times ratio^2 across)
    assert np.linalg.norm(g_along) == pytest.approx(2 * eps / SIGMA_T**2, rel=1e-9)
    assert np.linalg.norm(g_side) == pytest.approx(2 * eps * ratio**2 / SIGMA_T**2, rel=1e-9)
    assert np.linalg.norm(g_side) / np.linalg.norm(g_along) == pytest.approx(ratio**2, rel=1e-9)
    # each gradient points back along its own displacement (no cross-talk)
    assert np.allclose(np.cross(g_along, ray), 0.0, atol=1e-9)
    assert np.allclose(np.cross(g_side, side), 0.0, atol=1e-9)


def test_isotropic_without_rays_is_the_old_anchor():
    t = torch.tensor([[0.01, -0.02, 0.005]], dtype=torch.float64)
    rho = torch.tensor([[0.002, 0.0, 0.001]], dtype=torch.float64)
    expected = float((t * t).sum() / SIGMA_T**2 + (rho * rho).sum() / SIGMA_R**2)
    assert float(anchor_term(rho, t, SIGMA_R, SIGMA_T)) == pytest.approx(expected, rel=1e-12)
    ray = torch.tensor([[0.0, 0.0, -1.0]], dtype=torch.float64)
    assert float(anchor_term(rho, t, SIGMA_R, SIGMA_T, ray, 1.0)) == pytest.approx(expected, rel=1e-12)
