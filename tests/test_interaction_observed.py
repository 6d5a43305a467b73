"""An observed push: ``r2s synth --push`` writes input/interaction/ that agrees with the
ground truth simulated in PyBullet; the push-prediction error (UCD, pose error) against
analytic values; a malformed interaction file is one clear error line."""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pybullet as pb
import pytest
import trimesh
from PIL import Image
from scipy.spatial.transform import Rotation

from conftest import write_tiny_input
from r2s.sim.export_scene import export_ground_truth
from r2s.interaction.predict import predict
from r2s.interaction.push import replay_push
from r2s.interaction.track import track_objects
from r2s.io.input_scene import load_camera, load_input
from r2s.io.interaction_input import load_observed_push, read_true_push
from r2s.io.mesh_io import load_mesh, save_mesh
from r2s.io.scene_json import read_gt_scene
from r2s.metrics.geometry import posed
from r2s.metrics.push_prediction import (motion_error, observed_points, push_ucd,
                                         unilateral_chamfer_mm)
from r2s.sim.pybullet_bodies import connect_direct
from r2s.sim.pybullet_scene import load_export_scene
from r2s.runner.base import run_stage
from r2s.stages.export import STAGE as EXPORT, Options as ExportOptions
from r2s.synth.generate import SynthOptions, synthesize
from r2s.synth.push import PushSettings

FAST_OBJECTS = ("003_cracker_box,004_sugar_box,008_pudding_box,009_gelatin_box,"
                "036_wood_block,077_rubiks_cube,jenga_block,061_foam_brick")


@pytest.fixture(scope="module")
def pushed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 160x120 scene of 4 boxes, perfect depth, with an observed push."""
    out = tmp_path_factory.mktemp("synth") / "pushed"
    summary = synthesize(out, SynthOptions(objects=FAST_OBJECTS, count=4, seed=4, noise=0.0,
                                           width=160, height=120, min_visible_px=20,
                                           push=True))
    assert summary["pushed_id"] >= 1
    return out


def _com_world(pose: np.ndarray, com: np.ndarray) -> np.ndarray:
    return pose[:3, :3] @ com + pose[:3, 3]


def _true_displacements(pushed: Path) -> dict:
    gt = read_gt_scene(pushed / "gt" / "scene.json")
    truth = read_true_push(pushed / "gt" / "push.json")
    return {o.id: _com_world(truth.final[o.id], np.asarray(o.com_in_object))
            - _com_world(np.asarray(o.world_from_object), np.asarray(o.com_in_object))
            for o in gt.objects}


def test_observed_push_files_are_valid_and_match_a_pybullet_replay(pushed: Path) -> None:
    obs = load_observed_push(pushed)
    assert obs is not None and obs.depth_after_m.shape == obs.masks_after.shape == (120, 160)
    assert obs.displacement_m == {}  # the motion is measured from the images, not given
    truth = read_true_push(pushed / "gt" / "push.json")
    assert obs.pushed_id == truth.pushed_id and truth.action == obs.action
    speed = obs.action.waypoints[0].speed_mps
    assert 0.05 <= speed <= 0.1  # a slow push, not a strike

    gt = read_gt_scene(pushed / "gt" / "scene.json")
    with tempfile.TemporaryDirectory() as work:
        client = connect_direct()
        try:
            loaded = load_export_scene(client, export_ground_truth(pushed, Path(work)))
            final = replay_push(client, loaded, obs.action)
        finally:
            pb.disconnect(physicsClientId=client)
    for o in gt.objects:
        com = np.asarray(o.com_in_object)
        np.testing.assert_allclose(_com_world(final[o.id], com),
                                   _com_world(truth.final[o.id], com), atol=1e-4)

    # Along the push, the object goes at most as far as the pusher passes its rearmost
    # point (travel_m), plus the slide after release v^2 / (2 mu g) < 1 mm.
    moved = _true_displacements(pushed)
    start = np.asarray(obs.action.start)
    direction = np.asarray(obs.action.waypoints[0].position) - start
    direction /= np.linalg.norm(direction)
    along = float(moved[obs.pushed_id] @ direction)
    assert 0.01 < along <= PushSettings().travel_m + 0.002
    others = [np.linalg.norm(d) for i, d in moved.items() if i != obs.pushed_id]
    assert max(others, default=0.0) < 0.01


def test_tracker_measures_the_true_motion_from_the_images(pushed: Path) -> None:
    """Registering the true meshes (at their true poses before) to the points seen after
    the push gives the true COM displacements: within 3 mm (4 boxes, 160x120 pixels)."""
    gt = read_gt_scene(pushed / "gt" / "scene.json")
    obs = load_observed_push(pushed)
    cam, _ = load_camera(pushed / "input" / "camera.json")
    inp = load_input(pushed)
    before = observed_points(inp.depth_m, inp.masks, cam.K, cam.world_from_camera)
    after = observed_points(obs.depth_after_m, obs.masks_after, cam.K, cam.world_from_camera)
    meshes = {o.id: load_mesh(pushed / "gt" / o.mesh) for o in gt.objects}
    tracked = track_objects(meshes, {o.id: np.asarray(o.world_from_object) for o in gt.objects},
                            {o.id: np.asarray(o.com_in_object) for o in gt.objects},
                            before, after, cam.world_from_camera[:3, 3],
                            np.asarray(gt.support.normal))
    truth = _true_displacements(pushed)
    assert obs.pushed_id in tracked
    assert np.linalg.norm(truth[obs.pushed_id]) > 0.01
    for oid, t in tracked.items():
        np.testing.assert_allclose(t.displacement_m, truth[oid], atol=3e-3)


def test_depth_after_shows_the_true_final_poses(pushed: Path) -> None:
    """UCD of the observed points after the push to the true meshes: ~0 at the true final
    poses (perfect depth; the renderer's depth is exact to 1e-6 m, the png rounds to 1 mm,
    so < 1 mm), and many times more for the pushed object left where it was."""
    obs = load_observed_push(pushed)
    truth = read_true_push(pushed / "gt" / "push.json")
    gt = read_gt_scene(pushed / "gt" / "scene.json")
    cam, _ = load_camera(pushed / "input" / "camera.json")
    points = observed_points(obs.depth_after_m, obs.masks_after, cam.K, cam.world_from_camera)
    meshes = {o.id: load_mesh(pushed / "gt" / o.mesh) for o in gt.objects}
    at_final = push_ucd(points, {i: posed(m, truth.final[i]) for i, m in meshes.items()})
    assert at_final["ucd_mm"] < 1.0 and not at_final["unmatched_ids"]
    start = {o.id: np.asarray(o.world_from_object) for o in gt.objects}
    p = truth.pushed_id
    left_behind = unilateral_chamfer_mm(points[p], posed(meshes[p], start[p]))
    pushed_at_final = next(o["ucd_mm"] for o in at_final["objects"] if o["id"] == p)
    assert left_behind > 5.0 and left_behind > 10.0 * pushed_at_final


def test_ucd_of_points_offset_from_a_convex_mesh_is_the_offset() -> None:
    """Points pushed out by d along the face normal of a convex body are exactly d from it;
    on a faceted sphere the facets' sagitta (< 0.05 mm here) is the only error."""
    offset_m = 0.003
    box = trimesh.creation.box([0.1, 0.06, 0.04])
    pts, faces = trimesh.sample.sample_surface_even(box, 3000, seed=1)
    pts = pts + offset_m * box.face_normals[faces]
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_matrix()
    pose[:3, 3] = [0.3, -0.1, 0.2]
    world_pts = pts @ pose[:3, :3].T + pose[:3, 3]
    assert unilateral_chamfer_mm(world_pts, posed(box, pose)) == pytest.approx(3.0, abs=1e-6)

    radius_m = 0.05
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=radius_m)
    dirs = np.random.default_rng(0).normal(size=(2000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    ucd = unilateral_chamfer_mm((radius_m + offset_m) * dirs, sphere)
    assert ucd == pytest.approx(3.0, abs=0.05)


def test_motion_error_of_known_motions() -> None:
    """Frames differ (reconstruction vs truth) but the same motion gives zero error; a
    prediction off by 10 mm / 5 degrees reads 10 mm / 5 degrees."""
    rng = np.random.default_rng(2)

    def pose(rotvec: np.ndarray, t: np.ndarray) -> np.ndarray:
        out = np.eye(4)
        out[:3, :3], out[:3, 3] = Rotation.from_rotvec(rotvec).as_matrix(), t
        return out

    true0, pred0 = pose(rng.normal(size=3), rng.normal(size=3)), pose(rng.normal(size=3),
                                                                       rng.normal(size=3))
    motion = pose(np.array([0, 0, 0.4]), np.array([0.05, 0.02, 0.0]))
    com = np.array([0.01, 0.0, 0.02])
    t_mm, r_deg = motion_error(pred0, motion @ pred0, true0, motion @ true0, com)
    assert t_mm == pytest.approx(0.0, abs=1e-9) and r_deg == pytest.approx(0.0, abs=1e-4)

    shifted = pose(np.zeros(3), np.array([0.0, 0.01, 0.0])) @ motion
    assert motion_error(pred0, shifted @ pred0, true0, motion @ true0, com)[0] == \
        pytest.approx(10.0, abs=1e-6)
    c = _com_world(motion @ true0, com)  # turning about the true COM keeps it in place
    turn = pose(np.zeros(3), c) @ pose(np.array([0, 0, np.radians(5)]), np.zeros(3)) \
        @ pose(np.zeros(3), -c)
    t_mm, r_deg = motion_error(pred0, turn @ motion @ pred0, true0, motion @ true0, com)
    assert t_mm == pytest.approx(0.0, abs=1e-6) and r_deg == pytest.approx(5.0, abs=1e-4)


# ---- a malformed input/interaction/ is one clear line ---------------------------------------

def _scene_with_export(tmp_path: Path) -> Path:
    """The tiny input (64x48) and a gt box exported, so that predict can run."""
    scene = write_tiny_input(tmp_path / "scene")
    (scene / "gt" / "meshes").mkdir(parents=True)
    save_mesh(trimesh.creation.box([0.1] * 3), scene / "gt" / "meshes" / "1.glb")
    pose = np.eye(4)
    pose[2, 3] = 0.05
    (scene / "gt" / "scene.json").write_text(json.dumps({
        "objects": [{"id": 1, "mesh": "meshes/1.glb", "world_from_object": pose.tolist(),
                     "mass_kg": 0.3, "friction": 0.5}],
        "support": {"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]}}))
    run_stage(EXPORT, scene, ExportOptions(source="gt"))
    (scene / "input" / "interaction").mkdir()
    (scene / "input" / "interaction" / "push.json").write_text(json.dumps({
        "start": [-0.12, 0.0, 0.04], "waypoints": [{"position": [0.0, 0.0, 0.04]}]}))
    return scene


def _predict_cli(scene: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "r2s.cli", "predict", str(scene)],
                          capture_output=True, text=True, timeout=120)


def _break_action(inter: Path) -> None:
    (inter / "push.json").write_text(json.dumps({
        "start": [-0.12, 0.0], "waypoints": [{"position": [0.0, 0.0, 0.04]}]}))


def _break_depth_size(inter: Path) -> None:
    Image.fromarray(np.full((10, 10), 500, np.uint16)).save(inter / "depth_after.png")


def _break_observed(inter: Path) -> None:
    (inter / "observed.json").write_text(json.dumps({"objects": [{"id": 1,
                                                                  "displacement_m": [0.1]}]}))


@pytest.mark.parametrize("breaker,where,what", [
    (_break_action, "push.json", "start"),
    (_break_depth_size, "depth_after.png", "wrong size 10x10"),
    (_break_observed, "observed.json", "displacement_m"),
], ids=["action", "depth_size", "observed"])
def test_malformed_interaction_is_one_error_line(tmp_path: Path, breaker, where, what) -> None:
    scene = _scene_with_export(tmp_path)
    assert "error" in predict(scene)  # the well-formed observed push replays by default
    breaker(scene / "input" / "interaction")
    proc = _predict_cli(scene)
    assert proc.returncode == 2  # InputError
    # pybullet's C module prints its build time to stderr when imported; not ours
    lines = [ln for ln in proc.stderr.strip().splitlines()
             if ln.strip() and not ln.startswith("pybullet build time")]
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    assert where in lines[0] and what in lines[0], lines[0]
