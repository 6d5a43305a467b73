"""Export: mass properties against formulas, and export/ -> PyBullet round trips that use
nothing but pybullet and the files (as an independent judge would)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pybullet as pb
import pytest
import trimesh

from r2s.geometry.mass_properties import mass_properties
from r2s.io.mesh_io import save_mesh
from r2s.runner.base import run_stage
from r2s.stages.export import STAGE as EXPORT, Options as ExportOptions


def test_box_mass_properties_match_formula():
    a, b, c = 0.1, 0.06, 0.04
    box = trimesh.creation.box([a, b, c])
    box.apply_translation([0.01, 0.02, 0.03])
    props = mass_properties(box, mass_kg=0.3)
    assert props.volume_m3 == pytest.approx(a * b * c, rel=1e-9)
    assert np.allclose(props.com_in_object, [0.01, 0.02, 0.03], atol=1e-9)
    expected = 0.3 / 12 * np.diag([b**2 + c**2, a**2 + c**2, a**2 + b**2])
    assert np.allclose(props.inertia_about_com, expected, rtol=1e-6, atol=1e-12)


def test_open_mesh_falls_back_to_convex_pieces():
    box = trimesh.creation.box([0.1, 0.1, 0.1])
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-2], process=False)
    props = mass_properties(open_box, [box], density_kg_m3=1000.0)
    assert props.mass_kg == pytest.approx(1.0, rel=1e-6)


def _gt_scene(root: Path) -> Path:
    """gt/ with a 10 cm box on the plane and an upright can standing on top of it."""
    (root / "gt" / "meshes").mkdir(parents=True)
    box = trimesh.creation.box([0.1, 0.1, 0.1])
    cyl = trimesh.creation.cylinder(radius=0.02, height=0.08, sections=32)
    save_mesh(box, root / "gt" / "meshes" / "1.glb")
    save_mesh(cyl, root / "gt" / "meshes" / "2.glb")
    box_pose = np.eye(4)
    box_pose[2, 3] = 0.05
    cyl_pose = np.eye(4)
    cyl_pose[:3, 3] = [0.0, 0.0, 0.14]
    scene = {
        "gravity": [0, 0, -9.81],
        "objects": [
            {"id": 1, "label": "box", "mesh": "meshes/1.glb", "world_from_object": box_pose.tolist(),
             "mass_kg": 0.5, "friction": 0.9, "com_in_object": [0, 0, 0]},
            {"id": 2, "label": "can", "mesh": "meshes/2.glb", "world_from_object": cyl_pose.tolist(),
             "mass_kg": 0.1, "friction": 0.9, "com_in_object": [0, 0, 0]},
        ],
        "support": {"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1], "friction": 0.8},
    }
    (root / "gt" / "scene.json").write_text(json.dumps(scene))
    return root


def _load_like_a_judge(export_dir: Path) -> tuple[int, dict[int, int], dict]:
    """Load export/scene.json with plain pybullet calls only."""
    scene = json.loads((export_dir / "scene.json").read_text())
    client = pb.connect(pb.DIRECT)
    pb.setGravity(*scene["gravity"], physicsClientId=client)
    plane = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=client)
    ground = pb.createMultiBody(0, plane, basePosition=scene["support"]["point"],
                                physicsClientId=client)
    pb.changeDynamics(ground, -1, lateralFriction=scene["support"]["friction"],
                      physicsClientId=client)
    bodies = {}
    for obj in scene["objects"]:
        files = [str(export_dir / f) for f in obj["collision_meshes"]]
        shape = pb.createCollisionShapeArray([pb.GEOM_MESH] * len(files), fileNames=files,
                                             physicsClientId=client)
        pose = np.asarray(obj["world_from_object"])
        from scipy.spatial.transform import Rotation

        body = pb.createMultiBody(obj["mass_kg"], shape, basePosition=pose[:3, 3].tolist(),
                                  baseOrientation=Rotation.from_matrix(pose[:3, :3]).as_quat().tolist(),
                                  baseInertialFramePosition=obj["com_in_object"],
                                  physicsClientId=client)
        pb.changeDynamics(body, -1, lateralFriction=obj["friction"], physicsClientId=client)
        bodies[obj["id"]] = body
    return client, bodies, scene


def test_gt_export_loads_in_pybullet_and_stays_at_rest(tmp_path: Path):
    root = _gt_scene(tmp_path / "scene")
    result = run_stage(EXPORT, root, ExportOptions(source="gt"))
    assert result.summary["objects"] == 2
    export = root / "export"
    scene = json.loads((export / "scene.json").read_text())
    assert scene["format"] == "r2s-scene" and scene["version"] == 1
    for obj in scene["objects"]:
        for key in ("visual_mesh", "collision_meshes", "world_from_object", "mass_kg",
                    "com_in_object", "friction", "restitution"):
            assert key in obj
        assert (export / obj["visual_mesh"]).is_file()
    client, bodies, scene = _load_like_a_judge(export)
    start = {i: np.array(pb.getBasePositionAndOrientation(b, physicsClientId=client)[0])
             for i, b in bodies.items()}
    assert np.allclose(start[1], [0, 0, 0.05], atol=1e-6)
    for _ in range(240):
        pb.stepSimulation(physicsClientId=client)
    for i, b in bodies.items():
        end = np.array(pb.getBasePositionAndOrientation(b, physicsClientId=client)[0])
        assert np.linalg.norm(end - start[i]) < 0.003, (i, end - start[i])
    pb.disconnect(client)


def test_exported_urdf_loads_with_mass_and_inertia(tmp_path: Path):
    root = _gt_scene(tmp_path / "scene")
    run_stage(EXPORT, root, ExportOptions(source="gt"))
    client = pb.connect(pb.DIRECT)
    body = pb.loadURDF(str(root / "export" / "urdf" / "1.urdf"),
                       flags=pb.URDF_USE_INERTIA_FROM_FILE, physicsClientId=client)
    info = pb.getDynamicsInfo(body, -1, physicsClientId=client)
    assert info[0] == pytest.approx(0.5)
    assert info[1] == pytest.approx(0.9)  # lateral friction
    assert np.allclose(info[2], [0.5 / 12 * 0.02] * 3, rtol=1e-4)
    pb.disconnect(client)


def test_mjcf_export_loads_in_mujoco_and_resting_box_stays(tmp_path: Path):
    mujoco = pytest.importorskip("mujoco")
    root = _gt_scene(tmp_path / "scene")
    run_stage(EXPORT, root, ExportOptions(source="gt"))
    model = mujoco.MjModel.from_xml_path(str(root / "export" / "scene.xml"))
    data = mujoco.MjData(model)
    assert model.nbody == 3  # world + two objects
    assert model.body_mass[1] == pytest.approx(0.5, rel=1e-6)
    mujoco.mj_forward(model, data)
    start = data.xpos[1:].copy()
    for _ in range(480):
        mujoco.mj_step(model, data)
    moved = np.linalg.norm(data.xpos[1:] - start, axis=1)
    assert moved.max() < 0.003, moved
