"""Stability metrics: pure checks on made-up trajectories, then PyBullet rollouts of boxes."""

from __future__ import annotations

import numpy as np
import pybullet as pb
import pytest
import trimesh
from helpers_export import Obj, pose, rot_x, write_export
from scipy.spatial.transform import Rotation

from r2s.metrics.stability import (object_stability, rotation_angle_deg, scene_stability,
                                   settling_time_s)
from r2s.sim.pybullet_bodies import connect_direct
from r2s.sim.pybullet_scene import load_export_scene
from r2s.sim.rollout import Trajectory, rollout

BOX_M = 0.1


# ---- pure -----------------------------------------------------------------------------


def _spinning_trajectory(total_deg: float, world_rot: np.ndarray = np.eye(3)) -> Trajectory:
    """One object turning about its z axis by ``total_deg`` and moving 3 cm along x in 1 s,
    at rest for t >= 0.5 s; expressed in a world frame rotated by ``world_rot``."""
    times = np.linspace(0.0, 1.0, 11)
    frac = np.clip(times / 0.5, 0.0, 1.0)
    poses = np.zeros((11, 1, 4, 4))
    for k, f in enumerate(frac):
        p = np.eye(4)
        p[:3, :3] = world_rot @ Rotation.from_euler("z", f * total_deg, degrees=True).as_matrix()
        p[:3, 3] = world_rot @ np.array([0.03 * f, 0.0, 0.0])
        poses[k, 0] = p
    moving = (times < 0.5)[:, None, None]
    lin = np.where(moving, world_rot @ np.array([0.06, 0.0, 0.0]), 0.0)
    ang = np.where(moving, world_rot @ np.radians([0.0, 0.0, 2 * total_deg]), 0.0)
    return Trajectory(ids=np.array([9]), times_s=times, world_from_object=poses,
                      linear_velocity_mps=lin.reshape(11, 1, 3),
                      angular_velocity_radps=ang.reshape(11, 1, 3),
                      com_in_object=np.array([[0.0, 0.0, 0.02]]))


def test_drifts_settling_and_speeds():
    traj = _spinning_trajectory(30.0)
    (s,) = object_stability(traj)
    # COM is on the z axis, so it moves exactly as the origin: 3 cm
    assert s.translation_drift_m == pytest.approx(0.03, abs=1e-12)
    assert s.rotation_drift_deg == pytest.approx(30.0, abs=1e-9)
    assert not s.stable  # 30 deg > 5 deg although 3 cm < 5 cm
    assert s.settling_time_s == pytest.approx(0.5)
    assert s.mean_linear_speed_mps == pytest.approx(0.06 * 5 / 11)
    assert s.mean_angular_speed_radps == pytest.approx(np.radians(60.0) * 5 / 11)
    (s,) = object_stability(_spinning_trajectory(4.0))
    assert s.stable
    (s,) = object_stability(_spinning_trajectory(4.0), rotation_threshold_deg=3.0)
    assert not s.stable


def test_com_drift_differs_from_origin_drift():
    traj = _spinning_trajectory(90.0)
    com_off = Trajectory(**{**traj.__dict__, "com_in_object": np.array([[0.05, 0.0, 0.0]])})
    (s,) = object_stability(com_off)
    # COM goes from (0.05, 0, 0) to (0.03, 0.05, 0)
    assert s.translation_drift_m == pytest.approx(np.hypot(0.02, 0.05), abs=1e-12)


def test_stability_is_frame_independent():
    world_rot = Rotation.from_euler("xyz", [20, -35, 50], degrees=True).as_matrix()
    a = object_stability(_spinning_trajectory(30.0))[0]
    b = object_stability(_spinning_trajectory(30.0, world_rot))[0]
    for key in ("translation_drift_m", "rotation_drift_deg", "settling_time_s",
                "mean_linear_speed_mps", "mean_angular_speed_radps"):
        assert getattr(b, key) == pytest.approx(getattr(a, key), abs=1e-9)


def test_settling_time_edges():
    t = np.array([0.0, 0.1, 0.2, 0.3])
    assert settling_time_s(t, np.array([True, True, True, True])) == 0.0
    assert settling_time_s(t, np.array([True, False, True, True])) == pytest.approx(0.2)
    assert settling_time_s(t, np.array([True, True, True, False])) == pytest.approx(0.3)
    assert rotation_angle_deg(np.eye(3), rot_x(np.radians(170.0))) == pytest.approx(170.0)


def test_scene_stability_means():
    traj = _spinning_trajectory(30.0)
    two = Trajectory(ids=np.array([1, 2]), times_s=traj.times_s,
                     world_from_object=np.concatenate([traj.world_from_object,
                                                       np.tile(np.eye(4), (11, 1, 1, 1))], axis=1),
                     linear_velocity_mps=np.concatenate([traj.linear_velocity_mps,
                                                         np.zeros((11, 1, 3))], axis=1),
                     angular_velocity_radps=np.concatenate([traj.angular_velocity_radps,
                                                            np.zeros((11, 1, 3))], axis=1),
                     com_in_object=np.zeros((2, 3)))
    scene = scene_stability(object_stability(two))
    assert scene["stability_ratio"] == 0.5
    assert scene["settling_time_s"] == pytest.approx(0.25)
    assert scene["mean_linear_speed_mps"] == pytest.approx(0.06 * 5 / 11 / 2)


# ---- PyBullet rollouts ----------------------------------------------------------------


def _roll(tmp_path, objects, duration_s=1.0, **support):
    write_export(tmp_path / "export", objects, **support)
    client = connect_direct()
    try:
        loaded = load_export_scene(client, tmp_path / "export")
        traj = rollout(client, loaded, duration_s=duration_s, rate_hz=240, record_hz=60)
    finally:
        pb.disconnect(client)
    return traj, object_stability(traj)


def _box():
    return trimesh.creation.box([BOX_M] * 3)


def test_rollout_shapes_and_times(tmp_path):
    objs = [Obj(1, _box(), pose([0, 0, BOX_M / 2])), Obj(2, _box(), pose([0.3, 0, BOX_M / 2]))]
    traj, _ = _roll(tmp_path, objs, duration_s=0.5)
    assert traj.times_s.shape == (31,) and traj.times_s[-1] == pytest.approx(0.5)
    assert traj.world_from_object.shape == (31, 2, 4, 4)
    assert traj.linear_velocity_mps.shape == (31, 2, 3)
    assert traj.ids.tolist() == [1, 2]
    np.testing.assert_allclose(traj.world_from_object[0, 1, :3, 3], [0.3, 0, BOX_M / 2], atol=1e-6)


def test_box_resting_on_plane_is_stable(tmp_path):
    # PyBullet inflates mesh pieces by a 1 mm margin: a box touching the plane is pushed up
    # by that 1 mm in the first steps, one placed 1 mm up does not move at all.
    _, (touching,) = _roll(tmp_path / "a", [Obj(1, _box(), pose([0, 0, BOX_M / 2]))])
    assert touching.stable and touching.translation_drift_m < 0.002
    assert touching.rotation_drift_deg < 0.1
    assert touching.settling_time_s <= 0.1
    _, (on_margin,) = _roll(tmp_path / "b", [Obj(1, _box(), pose([0, 0, BOX_M / 2 + 0.001]))])
    assert on_margin.stable and on_margin.translation_drift_m < 1e-4
    assert on_margin.settling_time_s == 0.0


def test_box_dropped_from_10cm_lands_and_is_unstable(tmp_path):
    traj, (s,) = _roll(tmp_path, [Obj(1, _box(), pose([0, 0, BOX_M / 2 + 0.10]))])
    assert s.translation_drift_m == pytest.approx(0.10, abs=0.003)
    assert not s.stable
    fall_s = np.sqrt(2 * 0.10 / 9.81)
    assert fall_s < s.settling_time_s < 0.6
    # free fall: the COM speed just before impact is g t
    k = int(np.searchsorted(traj.times_s, 0.1))
    assert traj.linear_velocity_mps[k, 0, 2] == pytest.approx(-9.81 * traj.times_s[k], rel=0.02)


@pytest.mark.parametrize("friction, slides", [(0.1, True), (1.5, False)])
def test_box_on_30_degree_incline(tmp_path, friction, slides):
    """tan(30 deg) = 0.58: the box slides when the contact friction (product of the two
    values, support 1.0) is 0.1 and stays when it is 1.5."""
    rot = rot_x(np.radians(30.0))
    normal = rot[:, 2]
    obj = Obj(1, _box(), pose(normal * BOX_M / 2, rot), friction=friction)
    _, (s,) = _roll(tmp_path, [obj], support_normal=normal, support_friction=1.0)
    if slides:
        accel = 9.81 * (np.sin(np.radians(30)) - 0.1 * np.cos(np.radians(30)))  # 4.06 m/s^2
        assert not s.stable
        assert s.translation_drift_m == pytest.approx(0.5 * accel * 1.0**2, rel=0.1)
        assert s.settling_time_s == pytest.approx(1.0)
    else:
        assert s.stable and s.translation_drift_m < 0.005 and s.rotation_drift_deg < 1.0
