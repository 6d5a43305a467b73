"""Pinhole geometry against a hand-made camera: analytic pixel <-> point."""

from __future__ import annotations

import numpy as np

from r2s.geometry.camera import backproject, camera_center, intrinsics, look_at, pixel_rays, project

# camera at (0, 0, 1) looking straight down: camera x = world x, camera y = world -y,
# camera z = world -z
WORLD_FROM_CAMERA = np.array([[1.0, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 1.0], [0, 0, 0, 1]])
K = np.array([[100.0, 0, 20.0], [0, 100.0, 10.0], [0, 0, 1]])


def test_backproject_analytic_pixels():
    depth = np.full((21, 41), np.nan)
    depth[10, 20] = 0.5   # principal point: straight below the camera, 0.5 m down
    depth[10, 30] = 0.8   # 10 px right: x_cam = 10 / 100 * 0.8 = 0.08
    depth[0, 20] = 1.0    # 10 px up: y_cam = -0.1 -> world y = +0.1
    pts, pix = backproject(depth, K, WORLD_FROM_CAMERA, return_pixels=True)
    by_pixel = {tuple(p): x for p, x in zip(pix.tolist(), pts)}
    np.testing.assert_allclose(by_pixel[(10, 20)], [0.0, 0.0, 0.5], atol=1e-12)
    np.testing.assert_allclose(by_pixel[(10, 30)], [0.08, 0.0, 0.2], atol=1e-12)
    np.testing.assert_allclose(by_pixel[(0, 20)], [0.0, 0.1, 0.0], atol=1e-12)
    assert len(pts) == 3


def test_invalid_depth_and_mask_are_skipped():
    depth = np.array([[0.5, np.nan, 0.0], [np.inf, -1.0, 0.7]])
    mask = np.array([[True, True, True], [True, True, False]])
    pts = backproject(depth, K, WORLD_FROM_CAMERA, mask)
    assert pts.shape == (1, 3)


def test_project_inverts_backproject_with_skew_and_any_pose():
    rng = np.random.default_rng(0)
    k = np.array([[120.0, 3.0, 31.5], [0, 110.0, 23.5], [0, 0, 1]])
    pose = look_at([0.4, -0.3, 0.5], [0.0, 0.05, 0.0])
    depth = rng.uniform(0.3, 1.2, size=(48, 64))
    pts, pix = backproject(depth, k, pose, return_pixels=True)
    uv, z = project(pts, k, pose)
    np.testing.assert_allclose(uv[:, 0], pix[:, 1], atol=1e-9)
    np.testing.assert_allclose(uv[:, 1], pix[:, 0], atol=1e-9)
    np.testing.assert_allclose(z, depth[pix[:, 0], pix[:, 1]], atol=1e-12)


def test_points_behind_the_camera_have_no_pixel():
    uv, z = project(np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 0.5]]), K, WORLD_FROM_CAMERA)
    assert z[0] < 0 and np.all(np.isnan(uv[0]))
    np.testing.assert_allclose(uv[1], [20.0, 10.0])
    np.testing.assert_allclose(z[1], 0.5)


def test_look_at_is_an_opencv_camera():
    eye, target = np.array([0.5, -0.5, 0.5]), np.array([0.0, 0.0, 0.0])
    pose = look_at(eye, target)
    rot = pose[:3, :3]
    np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(rot), 1.0)
    np.testing.assert_allclose(rot[:, 2], (target - eye) / np.linalg.norm(target - eye))
    assert rot[2, 1] < 0  # image down (camera +y) points down in the world
    np.testing.assert_allclose(camera_center(pose), eye)
    uv, _ = project(target[None], intrinsics(64, 48, 60.0), pose)
    np.testing.assert_allclose(uv[0], [31.5, 23.5], atol=1e-9)


def test_pixel_rays_hit_backprojected_points():
    pose = look_at([0.3, 0.2, 0.6], [0.0, 0.0, 0.0])
    k = intrinsics(32, 24, 50.0)
    origins, dirs = pixel_rays(k, pose, 32, 24)
    depth = np.full((24, 32), 0.7)
    pts = backproject(depth, k, pose).reshape(24, 32, 3)
    np.testing.assert_allclose(origins + 0.7 * dirs, pts, atol=1e-12)
