"""The table's distance from the camera as evidence (r2s/diagnose/stats/table_height.py).

A table plane z = 0 seen by an oblique camera 0.5 m up, its points back-projected exactly
(no noise): each effect is made on the points the way the sensor or a wrong declaration
makes it, so every expected number is known. The world's origin lies on the table (the
scene format's convention: the support of gt/scene.json passes through it).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from r2s.diagnose.data import RegistrationData, Residuals, ScaleObs, SupportData
from r2s.diagnose.effects import all_effects, get_effect
from r2s.diagnose.effects._depth_model import support_refitted
from r2s.diagnose.stats.blocks import blocks_of
from r2s.diagnose.stats.ranking import NoiseBar, diagnose
from r2s.diagnose.stats.table_height import declares_table, with_height

K = np.array([[300.0, 0.0, 160.0], [0.0, 300.0, 120.0], [0.0, 0.0, 1.0]])
NOISE = NoiseBar(draws=100, quantile=0.99, seed=0)


def _true_world_from_camera(camera_xy=(-0.35, 0.0), height_m=0.5) -> np.ndarray:
    """A camera at ``height_m`` above the table, looking at the world origin."""
    c = np.array([camera_xy[0], camera_xy[1], height_m])
    fwd = -c / np.linalg.norm(c)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    t = np.eye(4)
    t[:3, :3] = np.stack([right, down, fwd], axis=1)
    t[:3, 3] = c
    return t


def _table_points_camera(world_from_camera, table_normal=(0.0, 0.0, 1.0)) -> np.ndarray:
    """(N, 3) camera-frame points where the pixel rays of a 320 x 240 image meet the plane
    through the world origin with ``table_normal``."""
    u, v = np.meshgrid(np.arange(0, 320, 8) + 0.5, np.arange(0, 240, 8) + 0.5)
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)],
                    axis=-1).reshape(-1, 3)
    rot, c = world_from_camera[:3, :3], world_from_camera[:3, 3]
    n = np.asarray(table_normal, dtype=float)
    n /= np.linalg.norm(n)
    dirs = rays @ rot.T
    depth = -(n @ c) / (dirs @ n)                      # ray parameter = camera z-depth
    pts = rays * depth[:, None]
    return pts[(depth > 0) & (depth < 3.0)]


def _support(points_camera, declared_world_from_camera, sigma_m=0.002) -> SupportData:
    c = declared_world_from_camera[:3, 3]
    base = SupportData(normal=np.array([0.0, 0.0, 1.0]), point=np.zeros(3), camera_center=c,
                       world_from_camera=declared_world_from_camera, height_sigma_m=sigma_m)
    fitted = support_refitted(base, points_camera)
    return SupportData(normal=fitted.normal, point=fitted.point, camera_center=c,
                       points_camera=fitted.points_camera, n_points=len(points_camera),
                       world_from_camera=declared_world_from_camera, height_sigma_m=sigma_m,
                       height_used=declares_table(fitted))


def _turned(world_from_camera, angle_deg, axis) -> np.ndarray:
    """The declared pose of a camera whose declared rotation is off by ``angle_deg``
    about ``axis`` (world), turned about its own centre."""
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    rot = Rotation.from_rotvec(np.radians(angle_deg) * axis)
    out = world_from_camera.copy()
    out[:3, :3] = rot.as_matrix() @ world_from_camera[:3, :3]
    return out


def test_a_level_table_through_the_origin_has_no_height_residual():
    pose = _true_world_from_camera()
    sup = _support(_table_points_camera(pose), pose)
    assert sup.height_used
    assert sup.height_m == pytest.approx(0.0, abs=1e-9)
    assert sup.camera_distance_m == pytest.approx(0.5, abs=1e-9)
    assert "table_height" in blocks_of(Residuals(support=sup))


def test_a_world_frame_off_the_table_is_not_evidence():
    """A world on a robot's base 0.75 m below the table: the height is left out."""
    pose = _true_world_from_camera()
    pose_robot = pose.copy()
    pose_robot[2, 3] += 0.75
    sup = _support(_table_points_camera(pose), pose_robot)
    assert sup.height_m == pytest.approx(-0.75, abs=1e-6)
    assert not sup.height_used
    assert "table_height" not in blocks_of(Residuals(support=sup))


def test_depth_scale_is_sized_by_the_table_alone():
    """A 4 % depth scale moves the table 20 mm away at 0.5 m; with no prior at all the
    scale is fitted to 0.1 % and named; the predicted height after it is zero."""
    pose = _true_world_from_camera()
    sup = _support(1.04 * _table_points_camera(pose), pose)
    assert sup.height_m == pytest.approx(0.02, abs=1e-6)
    res = Residuals(support=sup)
    fit = get_effect("depth_scale").fit(res)
    assert fit.identifiable and fit.size == pytest.approx(1.04, abs=0.001)
    assert fit.residuals_after.support.height_m == pytest.approx(0.0, abs=2e-4)
    d = diagnose(res, all_effects(), max_effects=2, noise=NOISE)
    assert [c.effect for c in d.chosen] == ["depth_scale"]


def test_depth_offset_is_sized_by_the_table_alone():
    """A 1 cm offset: the table's height asks for it to within a millimetre (its bend is
    small at this view; the height is the larger part of the evidence)."""
    pose = _true_world_from_camera()
    pts = _table_points_camera(pose)
    z = pts[:, 2:3]
    sup = _support(pts * (z + 0.01) / z, pose)
    fit = get_effect("depth_offset").fit(Residuals(support=sup))
    assert fit.identifiable
    assert fit.params["offset_m"] == pytest.approx(0.01, abs=0.001)


def test_a_camera_rotation_keeps_the_distance_and_a_tilted_table_does_not():
    """Rotating the declared camera about its centre tilts the fitted table but keeps its
    distance: camera_rotation explains everything, table_tilt leaves the height. A table
    tilted 2.5 deg about the origin, seen from 0.35 m aside, moves 15 mm nearer or farther:
    table_tilt explains it, the camera cannot, and the tilt is named against the 4:1 prior
    for the camera that the normal alone would follow."""
    pose = _true_world_from_camera()
    cam = _support(_table_points_camera(pose), _turned(pose, 3.0, [0.3, 1.0, 0.0]))
    assert cam.height_used and cam.height_m == pytest.approx(0.0, abs=1e-6)
    d = diagnose(Residuals(support=cam), all_effects(), max_effects=2, noise=NOISE)
    assert [c.effect for c in d.chosen] == ["camera_rotation"]
    assert d.chosen[0].residuals_after.support.height_m == pytest.approx(0.0, abs=1e-6)

    tilt_axis = np.array([0.0, 1.0, 0.0])
    normal = Rotation.from_rotvec(np.radians(2.5) * tilt_axis).apply([0.0, 0.0, 1.0])
    table = _support(_table_points_camera(pose, normal), pose)
    expected = float(normal @ pose[:3, 3]) - 0.5   # plane through the origin
    assert table.height_m == pytest.approx(expected, abs=1e-6)
    assert abs(expected) > 0.015
    camera_fit = get_effect("camera_rotation").fit(Residuals(support=table))
    tilt_fit = get_effect("table_tilt").fit(Residuals(support=table))
    assert camera_fit.residuals_after.support.height_m == pytest.approx(expected, abs=1e-6)
    assert tilt_fit.residuals_after.support.height_m == pytest.approx(0.0, abs=1e-6)
    d = diagnose(Residuals(support=table), all_effects(), max_effects=2, noise=NOISE)
    assert [c.effect for c in d.chosen] == ["table_tilt"]
    assert d.chosen[0].size == pytest.approx(2.5, abs=0.01)


def test_depth_scale_and_camera_rotation_together():
    """A 4 % scale with a 3 deg camera error, priors 2 % apart: both are named and sized
    (the scale from the distance, which the rotation keeps), whichever comes first."""
    pose = _true_world_from_camera()
    sup = _support(1.04 * _table_points_camera(pose), _turned(pose, 3.0, [1.0, 0.4, 0.0]))
    rng = np.random.default_rng(3)
    reg = RegistrationData(tuple(ScaleObs(id=i, scale=float(1.04 * np.exp(rng.normal(0, 0.02))),
                                          depth_m=0.55, fitness=0.9, n_points=500)
                                 for i in range(1, 6)), scale_sigma=0.025)
    d = diagnose(Residuals(registration=reg, support=sup), all_effects(), max_effects=3,
                 noise=NOISE)
    found = {c.effect: c for c in d.chosen}
    assert set(found) == {"depth_scale", "camera_rotation"}
    assert found["depth_scale"].size == pytest.approx(1.04, abs=0.004)
    assert found["camera_rotation"].size == pytest.approx(3.0, abs=0.05)


def test_height_noise_alone_names_nothing():
    """A level table found 1 mm off (half the noise level) and priors that agree with 1:
    no effect, and the noise bar of a depth scale is above what that height explains."""
    pose = _true_world_from_camera()
    sup = with_height(_support(_table_points_camera(pose), pose), 0.001)
    assert sup.height_m == pytest.approx(0.001, abs=1e-9)
    rng = np.random.default_rng(5)
    reg = RegistrationData(tuple(ScaleObs(id=i, scale=float(np.exp(rng.normal(0, 0.02))),
                                          depth_m=0.55, fitness=0.9, n_points=500)
                                 for i in range(1, 6)), scale_sigma=0.025)
    d = diagnose(Residuals(registration=reg, support=sup), all_effects(), max_effects=2,
                 noise=NOISE)
    assert d.chosen == ()


@pytest.mark.parametrize("angle_deg", [3.0, -3.0])
def test_lookahead_prefers_camera_and_scale_to_a_table_tilt_that_takes_the_height(angle_deg):
    """A 4 % scale with the camera pitched 3 deg. Pitched one way, a table tilted through
    the origin lies 18 mm farther, about what the scale did (20 mm), so one effect at a
    time takes the table tilt or a focal length (each explains the tilt and the distance;
    the camera only the tilt) and stops there. The priors still say 1.04: the camera then the scale explain
    everything, and the two-step lookahead takes the camera."""
    pose = _true_world_from_camera()
    sup = _support(1.04 * _table_points_camera(pose), _turned(pose, angle_deg, [0.0, 1.0, 0.0]))
    rng = np.random.default_rng(7)
    reg = RegistrationData(tuple(ScaleObs(id=i, scale=float(1.04 * np.exp(rng.normal(0, 0.01))),
                                          depth_m=0.55, fitness=0.9, n_points=500)
                                 for i in range(1, 6)), scale_sigma=0.025)
    res = Residuals(registration=reg, support=sup)
    greedy = diagnose(res, all_effects(), max_effects=3, noise=NOISE, lookahead=False)
    ahead = diagnose(res, all_effects(), max_effects=3, noise=NOISE)
    found = {c.effect: c for c in ahead.chosen}
    assert set(found) == {"depth_scale", "camera_rotation"}
    assert found["depth_scale"].size == pytest.approx(1.04, abs=0.004)
    assert found["camera_rotation"].size == pytest.approx(3.0, abs=0.05)
    # pitched one way, one effect at a time takes an effect that explains the tilt and the
    # distance together (a table tilted through the origin, or a focal length) and stops
    # there; the other way the greedy order was right already
    if angle_deg < 0:
        assert greedy.chosen[0].effect in ("table_tilt", "focal_length")
        assert {c.effect for c in greedy.chosen} != set(found)
    else:
        assert [c.effect for c in greedy.chosen] == ["camera_rotation", "depth_scale"]
