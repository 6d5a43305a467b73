"""A declared camera pose that tilts the table beyond any real table: levelled, with a warning.

The hand-made scene of ``helpers_diagnose`` declared with ``world_from_camera`` = identity
(a user who does not know the extrinsics): the declared world is the camera frame, where
the table's normal is the true up seen from the camera. Known answer: the tilt is the angle
between that vector and +z, and after the correction the camera sees up where the true
camera does (the turn about the vertical is not observable and is not asserted).
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from helpers_diagnose import input_scene, render, write_scene
from r2s.geometry.declared_level import GROSS_TILT_DEG
from r2s.io.input_scene import Camera
from r2s.scene_model import levelled


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b),
                                              -1.0, 1.0))))


def _declared(scene, world_from_camera: np.ndarray):
    cam = scene.camera
    return replace(scene, camera=Camera(K=cam.K, world_from_camera=world_from_camera,
                                        width=cam.width, height=cam.height))


def test_an_identity_pose_is_levelled_with_a_warning():
    true_pose = render()["world_from_camera"]
    up_in_camera = true_pose[:3, :3].T @ np.array([0.0, 0.0, 1.0])
    expected_tilt = _angle_deg(up_in_camera, np.array([0.0, 0.0, 1.0]))
    assert expected_tilt > GROSS_TILT_DEG  # the test bites
    scene = _declared(input_scene(), np.eye(4))
    out = levelled(scene)
    assert out is not scene
    note = out.warnings[-1]
    assert note.startswith("camera.json: world_from_camera tilts the table by ")
    assert float(note.split(" by ")[1].split(" deg")[0]) == pytest.approx(expected_tilt, abs=0.2)
    corrected = out.camera.world_from_camera
    # the camera sees the corrected world's up where the true camera sees the true up
    assert _angle_deg(corrected[:3, :3].T @ np.array([0.0, 0.0, 1.0]), up_in_camera) < 0.2
    # turned about the camera centre, which stays where it was declared
    assert np.allclose(corrected[:3, 3], 0.0, atol=1e-9)
    assert np.allclose(corrected[:3, :3] @ corrected[:3, :3].T, np.eye(3), atol=1e-9)


def test_a_few_degrees_are_left_to_diagnose():
    true_pose = render()["world_from_camera"]
    off = true_pose.copy()
    off[:3, :3] = Rotation.from_rotvec(np.radians(10.0) * np.array([1.0, 0.0, 0.0])
                                       ).as_matrix() @ true_pose[:3, :3]
    scene = _declared(input_scene(), off)
    assert levelled(scene) is scene
    clean = input_scene()
    assert levelled(clean) is clean


def test_a_wall_larger_than_the_table_does_not_turn_a_right_pose():
    r = render(wall_y_m=0.11, table_size_m=0.5)
    masks = r["masks"]
    depth = np.where(r["depth"] > 0, r["depth"], np.nan)
    from r2s.geometry.camera import backproject

    background = backproject(depth, r["K"], r["world_from_camera"], masks == 0)
    on_wall = np.abs(background[:, 1] - 0.11) < 0.005
    on_table = np.abs(background[:, 2]) < 0.005
    assert on_wall.sum() > on_table.sum()  # the test bites: the wall is the largest plane
    scene = input_scene(wall_y_m=0.11, table_size_m=0.5)
    assert levelled(scene) is scene


@pytest.mark.slow
def test_init_levels_an_identity_pose(tmp_path):
    from r2s.runner.base import run_stage
    from r2s.runner.registry import get_stage

    scene = write_scene(tmp_path / "scene")
    camera = json.loads((scene / "input" / "camera.json").read_text())
    camera["world_from_camera"] = np.eye(4).tolist()
    (scene / "input" / "camera.json").write_text(json.dumps(camera))
    (scene / "input" / "objects.json").unlink()  # the priors' poses were in the true world
    init = get_stage("init")
    run_stage(init, scene, init.options_type())
    state = json.loads((scene / "init" / "state.json").read_text())
    assert state["support"]["normal"][2] == pytest.approx(1.0, abs=1e-4)
    assert state["gravity"] == [0.0, 0.0, -9.81]
    manifest = json.loads((scene / "manifest.json").read_text())
    flags = manifest["stages"]["init"]["summary"]["flags"]
    assert any(f.startswith("camera.json: world_from_camera tilts the table by ") for f in flags)
    # the completed objects stand on the levelled table
    import trimesh

    for obj in state["objects"]:
        mesh = trimesh.load(scene / "init" / obj["mesh"], force="mesh")
        lowest = (mesh.vertices @ np.asarray(obj["world_from_object"])[:3, :3].T
                  + np.asarray(obj["world_from_object"])[:3, 3])[:, 2].min()
        height = lowest - state["support"]["point"][2]
        assert -0.004 < height < 0.01, (obj["id"], height)

    # the export says how its world relates to the declared one, and where gravity points there
    export = get_stage("export")
    run_stage(export, scene, export.options_type())
    declared = json.loads((scene / "export" / "declared_world.json").read_text())
    true_pose = render()["world_from_camera"]
    expected = true_pose[:3, :3].T @ np.array([0.0, 0.0, -9.81])  # the true down, camera frame
    assert _angle_deg(np.asarray(declared["gravity_declared_world"]), expected) < 0.3
    assert np.linalg.norm(declared["gravity_declared_world"]) == pytest.approx(9.81, abs=1e-6)
    assert np.allclose(np.asarray(declared["corrected_from_declared"])
                       @ np.asarray(declared["declared_from_corrected"]), np.eye(4), atol=1e-9)
    assert json.loads((scene / "export" / "scene.json").read_text())["gravity"] == [0.0, 0.0, -9.81]
    # the viewer (and predict) place the input camera in the export's world: the observed
    # table is then level, at the support's height; in the declared world it is not
    from r2s.io.paths import ScenePaths
    from r2s.viewer.scene_data import observed_points

    support_z = state["support"]["point"][2]
    points, _, _, _ = observed_points(ScenePaths(scene))
    assert np.mean(np.abs(points[:, 2] - support_z) < 0.005) > 0.5
    # and predict replays a push given in the declared world in the export's world
    from r2s.interaction.predict import _in_export_world
    from r2s.io.push_action import PushAction

    push = PushAction(start=[0.0, 0.0, 0.5], waypoints=[{"position": [0.0, 0.1, 0.5]}])
    moved = _in_export_world(push, ScenePaths(scene))
    t = np.asarray(declared["corrected_from_declared"])
    assert np.allclose(moved.start, t[:3, :3] @ [0.0, 0.0, 0.5] + t[:3, 3], atol=1e-12)
    assert np.allclose(moved.waypoints[0].position,
                       t[:3, :3] @ [0.0, 0.1, 0.5] + t[:3, 3], atol=1e-12)
    assert moved.waypoints[0].speed_mps == push.waypoints[0].speed_mps
    (scene / "export" / "declared_world.json").unlink()
    points, _, _, _ = observed_points(ScenePaths(scene))
    assert np.mean(np.abs(points[:, 2] - support_z) < 0.005) < 0.2
    assert _in_export_world(push, ScenePaths(scene)).start == push.start
