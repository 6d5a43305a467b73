"""The export's USD, combined GLB and MJCF scenes against scene.json and analytic values."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from helpers_scene_export import (BOX_FRICTION, BOX_MASS_KG, CAN_FRICTION, SUPPORT_FRICTION,
                                  exported_scene)
from r2s.io.scene_glb import Y_UP_FROM_Z_UP

REPO = Path(__file__).resolve().parents[1]
BOX_INERTIA = BOX_MASS_KG / 12 * (0.1 ** 2 + 0.1 ** 2)   # kg m^2, each axis of the cube


@pytest.fixture(scope="module")
def export_dir(tmp_path_factory) -> Path:
    return exported_scene(tmp_path_factory.mktemp("scene"))


@pytest.fixture(scope="module")
def scene(export_dir: Path) -> dict:
    return json.loads((export_dir / "scene.json").read_text())


# ---- USD ------------------------------------------------------------------------------
def test_usd_stage_units_gravity_and_bodies_match_scene_json(export_dir: Path, scene: dict):
    from pxr import Gf, Usd, UsdGeom, UsdPhysics, UsdShade

    stage = Usd.Stage.Open(str(export_dir / "scene.usda"))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert UsdPhysics.GetStageKilogramsPerUnit(stage) == 1.0
    phys = UsdPhysics.Scene(stage.GetPrimAtPath("/World/PhysicsScene"))
    assert np.allclose(phys.GetGravityDirectionAttr().Get(), [0, 0, -1])
    assert phys.GetGravityMagnitudeAttr().Get() == pytest.approx(9.81, rel=1e-6)
    cache = UsdGeom.XformCache()
    for obj in scene["objects"]:
        prim = stage.GetPrimAtPath(f"/World/object_{obj['id']}")
        assert prim.HasAPI(UsdPhysics.RigidBodyAPI) and prim.HasAPI(UsdPhysics.MassAPI)
        mass = UsdPhysics.MassAPI(prim)
        assert mass.GetMassAttr().Get() == pytest.approx(obj["mass_kg"], rel=1e-6)
        assert np.allclose(mass.GetCenterOfMassAttr().Get(), obj["com_in_object"], atol=1e-7)
        q = mass.GetPrincipalAxesAttr().Get()
        axes = Rotation.from_quat([*q.GetImaginary(), q.GetReal()]).as_matrix()
        tensor = axes @ np.diag(mass.GetDiagonalInertiaAttr().Get()) @ axes.T
        assert np.allclose(tensor, obj["inertia_about_com"], rtol=1e-5, atol=1e-9)
        world = np.asarray(cache.GetLocalToWorldTransform(prim)).T
        assert np.allclose(world, obj["world_from_object"], atol=1e-9)
        pieces = [p for p in Usd.PrimRange(prim) if p.HasAPI(UsdPhysics.CollisionAPI)]
        assert len(pieces) == len(obj["collision_meshes"])
        for p in pieces:
            assert UsdPhysics.MeshCollisionAPI(p).GetApproximationAttr().Get() == "convexHull"
            assert UsdGeom.Imageable(p).GetPurposeAttr().Get() == UsdGeom.Tokens.guide
            bound = UsdShade.MaterialBindingAPI(p).ComputeBoundMaterial("physics")[0]
            mat = UsdPhysics.MaterialAPI(bound.GetPrim())
            assert mat.GetStaticFrictionAttr().Get() == pytest.approx(obj["friction"])
            assert mat.GetDynamicFrictionAttr().Get() == pytest.approx(obj["friction"])
        visual = stage.GetPrimAtPath(f"/World/object_{obj['id']}/visual")
        assert not visual.HasAPI(UsdPhysics.CollisionAPI)
        assert UsdGeom.PrimvarsAPI(visual).GetPrimvar("st").HasValue()
    box = UsdPhysics.MassAPI(stage.GetPrimAtPath("/World/object_1"))
    assert np.allclose(box.GetDiagonalInertiaAttr().Get(), [BOX_INERTIA] * 3, rtol=1e-4)
    support = stage.GetPrimAtPath("/World/support")
    assert support.HasAPI(UsdPhysics.CollisionAPI)
    assert not support.HasAPI(UsdPhysics.RigidBodyAPI)


def test_usd_camera_projects_like_the_input_camera(export_dir: Path):
    """A world point projects to the same pixel through the USD camera as through K."""
    from pxr import Gf, Usd, UsdGeom

    stage = Usd.Stage.Open(str(export_dir / "scene.usda"))
    cam_json = json.loads((export_dir.parent / "input" / "camera.json").read_text())
    K, pose, w, h = (np.asarray(cam_json["K"]), np.asarray(cam_json["world_from_camera"]),
                     cam_json["width"], cam_json["height"])
    gf_cam = UsdGeom.Camera(stage.GetPrimAtPath("/World/input_camera")).GetCamera(
        Usd.TimeCode.Default())
    frustum = gf_cam.frustum
    view_proj = frustum.ComputeViewMatrix() * frustum.ComputeProjectionMatrix()
    for point in ([0.02, -0.01, 0.05], [0.07, 0.03, 0.1], [-0.03, -0.05, 0.0]):
        cam_pt = np.linalg.inv(pose) @ np.append(point, 1.0)
        u, v = (K @ (cam_pt[:3] / cam_pt[2]))[:2]
        ndc = view_proj.Transform(Gf.Vec3d(*point))
        u_usd = (ndc[0] + 1) / 2 * w
        v_usd = (1 - ndc[1]) / 2 * h
        # USD's image plane spans pixel edges; K's principal point is in pixel centres
        assert u_usd - 0.5 == pytest.approx(u, abs=1e-6)
        assert v_usd - 0.5 == pytest.approx(v, abs=1e-6)


# ---- combined GLB ---------------------------------------------------------------------
def test_scene_glb_places_every_object_in_y_up(export_dir: Path, scene: dict):
    loaded = trimesh.load(export_dir / "scene.glb", force="scene")
    for obj in scene["objects"]:
        name = f"object_{obj['id']}"
        transform, geom_name = loaded.graph[name]
        got = trimesh.transform_points(loaded.geometry[geom_name].vertices, transform)
        mesh = trimesh.load(export_dir / obj["visual_mesh"], force="mesh")
        world = trimesh.transform_points(mesh.vertices, np.asarray(obj["world_from_object"]))
        expected = np.stack([world[:, 0], world[:, 2], -world[:, 1]], axis=1)
        assert np.abs(got - expected).max() < 1e-5
    transform, geom = loaded.graph["object_1"]
    centre = trimesh.transform_points(loaded.geometry[geom].vertices, transform).mean(0)
    # the box's centre at world (0.02, -0.01, 0.05) is (0.02, 0.05, 0.01) in glTF
    assert np.allclose(centre, [0.02, 0.05, 0.01], atol=1e-6)
    assert np.allclose(Y_UP_FROM_Z_UP[:3, :3] @ [0, 0, 1], [0, 1, 0])


def _validator() -> tuple[str, dict]:
    node = shutil.which("node")
    modules = REPO / ".node" / "node_modules"
    if node is None:
        pytest.skip("node is not installed (the Khronos glTF validator runs on node)")
    if not (modules / "gltf-validator").is_dir():
        pytest.skip("gltf-validator is not installed (scripts/setup_env.sh: npm install "
                    "--prefix .node gltf-validator)")
    return node, {**os.environ, "NODE_PATH": str(modules)}


@pytest.mark.parametrize("name", ["scene.glb", "meshes/1.glb"])
def test_glb_passes_the_khronos_validator(export_dir: Path, name: str):
    node, env = _validator()
    out = subprocess.run([node, str(REPO / "scripts" / "validate_gltf.js"),
                          str(export_dir / name)], capture_output=True, text=True, env=env,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    issues = json.loads(out.stdout)
    assert issues["numErrors"] == 0, issues["messages"][:5]
    assert issues["numWarnings"] == 0, issues["messages"][:5]


# ---- MJCF -----------------------------------------------------------------------------
def test_mjcf_visuals_camera_table_and_product_friction(export_dir: Path, scene: dict):
    mujoco = pytest.importorskip("mujoco")
    model = mujoco.MjModel.from_xml_path(str(export_dir / "scene.xml"))
    data = mujoco.MjData(model)
    for obj in scene["objects"]:
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"object_{obj['id']}")
        assert model.body_mass[body] == pytest.approx(obj["mass_kg"], rel=1e-6)
        vis = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"visual_{obj['id']}")
        assert model.geom_contype[vis] == 0 and model.geom_conaffinity[vis] == 0
        assert model.geom_group[vis] == 1
        assert model.geom_matid[vis] >= 0 and model.mat_texid[model.geom_matid[vis]].max() >= 0
    assert model.geom_type[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "support")] \
        == mujoco.mjtGeom.mjGEOM_PLANE
    cam = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "input_camera")
    cam_json = json.loads((export_dir.parent / "input" / "camera.json").read_text())
    fovy = np.degrees(2 * np.arctan(0.5 * cam_json["height"] / cam_json["K"][1][1]))
    assert model.cam_fovy[cam] == pytest.approx(fovy, rel=1e-5)  # MJCF keeps 6 digits
    mujoco.mj_forward(model, data)
    mujoco.mj_step(model, data)
    seen = {}
    for c in data.contact[:data.ncon]:
        bodies = tuple(sorted((int(model.geom_bodyid[c.geom1]), int(model.geom_bodyid[c.geom2]))))
        seen[bodies] = c.friction[0]
    # the box (body 1) on the table (body 0), the can (body 2) on the box: PyBullet's products
    assert seen[(0, 1)] == pytest.approx(BOX_FRICTION * SUPPORT_FRICTION, rel=1e-9)
    assert seen[(1, 2)] == pytest.approx(BOX_FRICTION * CAN_FRICTION, rel=1e-9)


def _lifts_in_both_engines(export_dir: Path, duration_s: float = 2.0):
    """(N, 3) object-origin displacement over the rollout in PyBullet and in MuJoCo."""
    from r2s.sim.mujoco_rollout import mujoco_rollout
    from r2s.sim.pybullet_bodies import connect_direct
    from r2s.sim.pybullet_scene import load_export_scene
    from r2s.sim.rollout import rollout
    import pybullet as pb

    client = connect_direct()
    try:
        pyb = rollout(client, load_export_scene(client, export_dir), duration_s)
    finally:
        pb.disconnect(client)
    mjc = mujoco_rollout(export_dir, duration_s)
    return tuple(t.world_from_object[-1, :, :3, 3] - t.world_from_object[0, :, :3, 3]
                 for t in (pyb, mjc))


def test_mjcf_stack_exported_in_contact_starts_at_rest(export_dir: Path):
    """The stack is exported in exact contact, inside Bullet's 1 mm margins. Bullet lifts
    each convex body by its margin (box 1 mm, can on box 3 mm); MuJoCo's contacts rest at
    the exported distance (pair margin 0), so nothing is pushed at the start."""
    mujoco = pytest.importorskip("mujoco")
    model = mujoco.MjModel.from_xml_path(str(export_dir / "scene.xml"))
    assert model.npair > 0
    touching = [k for k in range(model.npair) if model.pair_margin[k] < 1e-3]
    assert touching, "no pair got the exported (zero) distance as its margin"
    assert np.abs(model.pair_margin[touching]).max() < 2e-5
    lift_pb, lift_mj = _lifts_in_both_engines(export_dir)
    assert np.allclose(lift_pb[:, 2], [0.001, 0.003], atol=2e-4)
    assert np.abs(lift_mj).max() < 1e-4                    # Bullet's margins would give 1 and 3 mm


def test_mjcf_rest_distances_match_pybullet_for_bodies_that_settle(tmp_path: Path):
    """Box 5 mm above the table, can 10 mm above the box's top: both fall and come to rest
    at Bullet's margins (box 1 mm up, can 1 + 2 mm up) in both engines."""
    pytest.importorskip("mujoco")
    export = exported_scene(tmp_path / "scene", box_lift_m=0.005, can_lift_m=0.015)
    lift_pb, lift_mj = _lifts_in_both_engines(export)
    assert np.allclose(lift_pb[:, 2], [0.001 - 0.005, 0.003 - 0.015], atol=2e-4)
    assert np.abs(lift_mj[:, 2] - lift_pb[:, 2]).max() < 1e-4   # the same rest heights
    assert np.abs(lift_mj[:, :2]).max() < 1e-3                  # the landing slides < 1 mm


@pytest.mark.parametrize("height_m, margin_m", [
    (0.0004, 0.0004),      # inside Bullet's margin: rests where exported
    (0.0, 0.0),            # touching
    (-0.0003, 0.0),        # overlapping: pushed out to touching, never kept inside
    (0.00095, 0.001),      # within REST_TOLERANCE_M of the margin: Bullet's margin kept
    (0.005, 0.001),        # apart: Bullet's margin
])
def test_fit_rest_distances_sets_each_pair_margin(height_m: float, margin_m: float):
    """A 10 cm box whose bottom face is ``height_m`` above a plane, one pair with a 1 mm
    margin: the fitted margin is the analytic distance, clamped as documented."""
    mujoco = pytest.importorskip("mujoco")
    from r2s.io.mjcf import fit_rest_distances

    spec = mujoco.MjSpec()
    plane = spec.worldbody.add_geom(name="support", type=mujoco.mjtGeom.mjGEOM_PLANE,
                                    size=[1.0, 1.0, 0.1])
    body = spec.worldbody.add_body(name="box", pos=[0.0, 0.0, 0.05 + height_m])
    body.add_freejoint()
    body.add_geom(name="c", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.05, 0.05, 0.05])
    spec.add_pair(geomname1=plane.name, geomname2="c", margin=0.001)
    distances = fit_rest_distances(spec)
    assert distances[0] == pytest.approx(min(height_m, 0.001), abs=1e-7)
    assert spec.compile().pair_margin[0] == pytest.approx(margin_m, abs=1e-7)


def test_urdf_visual_is_the_textured_obj(export_dir: Path):
    urdf = (export_dir / "urdf" / "1.urdf").read_text()
    assert "../visual/1.obj" in urdf
    mtl = (export_dir / "visual" / "1.mtl").read_text()
    assert "map_Kd 1.png" in mtl and (export_dir / "visual" / "1.png").is_file()


def test_mjcf_input_camera_sees_the_box_where_k_projects_it(export_dir: Path, scene: dict):
    """Segmentation render of the visual geoms from ``input_camera``: the box's pixels
    centre where ray casting through K puts them (within 0.5 px; the principal point is off
    the image centre by (3, -4) px)."""
    mujoco = pytest.importorskip("mujoco")
    model = mujoco.MjModel.from_xml_path(str(export_dir / "scene.xml"))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    cam_json = json.loads((export_dir.parent / "input" / "camera.json").read_text())
    w, h = cam_json["width"], cam_json["height"]
    try:
        renderer = mujoco.Renderer(model, h, w)
    except Exception as exc:  # no OpenGL context on this machine
        pytest.skip(f"MuJoCo cannot render here ({type(exc).__name__}: {exc})")
    opt = mujoco.MjvOption()
    opt.geomgroup[:] = [0, 1, 0, 0, 0, 0]
    renderer.enable_segmentation_rendering()
    renderer.update_scene(data, camera="input_camera", scene_option=opt)
    seg = renderer.render()[..., 0]
    renderer.close()
    box_geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "visual_1")
    vs, us = np.nonzero(seg == box_geom)
    assert len(us) > 100
    # the same mask by ray casting the box through K (pixel centres)
    K, pose = np.asarray(cam_json["K"]), np.asarray(cam_json["world_from_camera"])
    box = trimesh.creation.box([0.1, 0.1, 0.1])
    box.apply_transform(np.asarray(scene["objects"][0]["world_from_object"]))
    can = trimesh.creation.cylinder(radius=0.02, height=0.08, sections=24)
    can.apply_transform(np.asarray(scene["objects"][1]["world_from_object"]))
    uu, vv = np.meshgrid(np.arange(w), np.arange(h))
    rays = np.stack([(uu - K[0, 2]) / K[0, 0], (vv - K[1, 2]) / K[1, 1], np.ones_like(uu, float)],
                    -1).reshape(-1, 3) @ pose[:3, :3].T
    origins = np.repeat(pose[None, :3, 3], len(rays), axis=0)
    both = trimesh.util.concatenate([box, can])
    hit_tri, hit_ray = both.ray.intersects_id(origins, rays, multiple_hits=False)
    on_box = hit_ray[hit_tri < len(box.faces)]
    expected = np.stack([uu.reshape(-1)[on_box], vv.reshape(-1)[on_box]], 1)
    assert np.allclose([us.mean(), vs.mean()], expected.mean(0), atol=0.5)


def test_pybullet_bodies_keep_every_convex_piece(tmp_path: Path):
    """createCollisionShapeArray drops pieces past 16; add_rigid_body must keep all 27."""
    import pybullet as pb
    from r2s.sim.pybullet_bodies import add_rigid_body, connect_direct

    files = []
    for k in range(27):
        piece = trimesh.creation.box([0.01, 0.01, 0.01])
        piece.apply_translation([0.02 * k, 0.0, 0.0])
        files.append(tmp_path / f"p{k}.obj")
        piece.export(files[-1])
    client = connect_direct()
    try:
        body = add_rigid_body(client, files, np.eye(4), 1.0, [0.26, 0.0, 0.0], 0.5)
        lo, hi = pb.getAABB(body, -1, physicsClientId=client)
        assert hi[0] == pytest.approx(0.527, abs=2e-3)  # the last piece's far face + margin
        assert lo[0] == pytest.approx(-0.005, abs=3e-3)
    finally:
        pb.disconnect(client)
