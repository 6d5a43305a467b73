"""Support plane fit: RANSAC + least squares on noisy points with outliers."""

from __future__ import annotations

import numpy as np
import pytest

from r2s.geometry.plane import fit_plane_ransac, signed_distance, world_from_plane


def _tilted_plane(n_in: int, outlier_fraction: float, noise_m: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    normal = np.array([0.05, -0.08, 1.0])
    normal /= np.linalg.norm(normal)
    point = np.array([0.1, -0.2, 0.03])
    u = np.cross(normal, [1.0, 0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    ab = rng.uniform(-0.5, 0.5, size=(n_in, 2))
    inliers = point + ab[:, :1] * u + ab[:, 1:] * v + rng.normal(0, noise_m, (n_in, 1)) * normal
    n_out = int(round(n_in * outlier_fraction / (1 - outlier_fraction)))
    outliers = point + rng.uniform(-0.5, 0.5, size=(n_out, 3)) * [1, 1, 0.4] + [0, 0, 0.2]
    pts = np.concatenate([inliers, outliers])
    return pts[rng.permutation(len(pts))], point, normal


def test_noisy_plane_with_30_percent_outliers():
    pts, point, normal = _tilted_plane(7000, 0.3, 0.002)
    fit = fit_plane_ransac(pts, threshold_m=0.005, seed=1)
    angle = np.degrees(np.arccos(np.clip(fit.normal @ normal, -1, 1)))
    assert angle < 0.5
    assert abs(fit.offset_m - normal @ point) < 0.002
    assert abs(signed_distance(point[None], fit.point, fit.normal)[0]) < 0.002
    # about 70 % of the points are on the plane (some outliers fall within the threshold)
    assert 0.68 < fit.inliers.mean() < 0.75


def test_normal_orientation_follows_hint_or_viewpoint():
    pts, _, normal = _tilted_plane(2000, 0.0, 0.001)
    assert fit_plane_ransac(pts).normal @ normal > 0.99
    assert fit_plane_ransac(pts, up_hint=[0, 0, -1]).normal @ normal < -0.99
    assert fit_plane_ransac(pts, viewpoint=[0, 0, -2.0]).normal @ normal < -0.99
    assert fit_plane_ransac(pts, viewpoint=[0, 0, 2.0]).normal @ normal > 0.99


def test_max_tilt_prefers_a_table_over_a_larger_wall():
    rng = np.random.default_rng(3)
    table = np.c_[rng.uniform(-0.3, 0.3, (3000, 2)), np.zeros(3000)]
    wall = np.c_[np.full(6000, 0.5), rng.uniform(-0.5, 0.5, 6000), rng.uniform(0, 1, 6000)]
    pts = np.concatenate([table, wall])
    assert abs(fit_plane_ransac(pts).normal[0]) > 0.99  # the wall holds more points
    fit = fit_plane_ransac(pts, max_tilt_deg=30)
    # wall points within the threshold of the floor join the fit and tilt it a little
    assert np.degrees(np.arccos(fit.normal[2])) < 0.1
    assert fit.inliers[:3000].all()
    assert not fit.inliers[3000:][wall[:, 2] > 0.01].any()


def test_deterministic_per_seed_and_rejects_degenerate_input():
    pts, _, _ = _tilted_plane(1000, 0.3, 0.002)
    a, b = fit_plane_ransac(pts, seed=5), fit_plane_ransac(pts, seed=5)
    np.testing.assert_array_equal(a.normal, b.normal)
    with pytest.raises(ValueError):
        fit_plane_ransac(np.zeros((2, 3)))


def test_world_from_plane_frame():
    normal = np.array([0.1, 0.2, 0.97])
    frame = world_from_plane([0.0, 0.0, 0.05], normal)
    rot = frame[:3, :3]
    np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(rot), 1.0)
    np.testing.assert_allclose(rot[:, 2], normal / np.linalg.norm(normal))
    assert rot[0, 0] > 0.9  # x follows world +x
