"""The scene's model (``manifest.model``, kept by ``r2s diagnose --set apply=true``) in the
stages that apply it, and in ``r2s run``'s staleness.

- depth scale 1.03 in the model: init's observed points are the raw back-projection
  pulled towards the camera centre by exactly 1/1.03 (1e-6 m, float32 storage), and the
  cylinder and ball priors register at scale 1 +- 0.006 (1.03 without the model);
  ``input/`` is untouched;
- a camera declared 2.5 deg off, its fitted correction in the model: init's table is
  level to 0.1 deg (2.5 deg without), so gravity is perpendicular to it;
- table tilt, COM offset, friction in the model: physopt starts from them and
  ``export/scene.json`` carries them (support normal = the fitted normal, gravity as
  declared, ``com_in_object`` and ``friction`` of the object);
- ``r2s run`` after a state-level effect is recorded reruns physopt and export only,
  after a depth effect init and everything after it, and then nothing; an unchanged
  model changes nothing; a scene without a model keeps the hashes it always had.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import snapshot
from helpers_diagnose import write_scene
from helpers_state import box, write_init_state
from r2s.diagnose.data import Residuals
from r2s.diagnose.effects import get_effect
from r2s.diagnose.measure.observe import support_residual
from r2s.scene_model import UnknownEffectError, corrected_state, model_part, with_effect
from r2s.errors import R2SError
from r2s.geometry.camera import backproject
from r2s.io.input_scene import load_input
from r2s.io.paths import ScenePaths
from r2s.io.state import read_state
from r2s.runner.pipeline import build_options, run_pipeline
from r2s.runner.base import model_hashes, run_stage, staleness
from r2s.io.manifest import Manifest, load_manifest, save_manifest
from r2s.runner.registry import get_stage

G = np.array([0.0, 0.0, -9.81])
FAST = {"physopt.use_diffsim": "false", "physopt.max_rounds": "1"}
"""Physopt without the torch optimisation and with one repair round: the tests are about
which stages run, not about how well physopt does."""

TILT = {"angle_deg": 2.0, "axis_world": [1.0, 0.0, 0.0],
        "normal_world": [0.0, -0.03489950, 0.99939083]}
COM = {"objects": {"1": {"shift_world_m": [0.01, 0.0, 0.0], "offset_in_object_m": [0.01, 0, 0],
                         "com_in_object_m": [0.01, 0.0, -0.005]}}}
FRICTION = {"objects": {"1": {"friction": 0.35, "default_friction": 0.8}}}


def _set_model(scene, model: dict) -> None:
    manifest = load_manifest(scene / "manifest.json")
    manifest.model = model
    save_manifest(scene / "manifest.json", manifest)


def _ran(results) -> list[str]:
    return [r.name for r in results if r.ran]


def _run(scene, **kwargs):
    return run_pipeline(scene, skip=["texture", "evaluate"], **kwargs)


# ---- input level: init ------------------------------------------------------------------

def test_depth_scale_in_the_model_scales_init_points_about_the_camera(tmp_path):
    s = 1.03
    scene = write_scene(tmp_path / "scene", depth_scale=s)
    before_input = snapshot(scene / "input")
    _set_model(scene, {"effects": {"depth_scale": {"scale": s, "offset_m": 0.0}}})
    # every masked pixel kept (the rim filter is tested in test_mask_edges.py)
    spec = get_stage("init")
    run_stage(spec, scene, build_options(spec, None, {"drop_foreign_rim": "false"}))
    assert snapshot(scene / "input") == before_input

    raw = load_input(scene)
    cam = raw.camera
    centre = cam.world_from_camera[:3, 3]
    state = read_state(scene / "init")
    for obj in state.objects:
        got = np.load(scene / "init" / f"points/{obj.id}.npy").astype(np.float64)
        raw_pts = backproject(raw.depth_m, cam.K, cam.world_from_camera, raw.masks == obj.id)
        assert got.shape == raw_pts.shape
        # depth / s moves every point along its ray: p' - c = (p - c) / s
        np.testing.assert_allclose(got, centre + (raw_pts - centre) / s, atol=1e-6)
        if obj.id in (2, 4):
            # the cylinder's and the ball's registered size now agrees with their priors
            # (uncorrected: 1.029, 1.030); init's scale of a box seen from one side is
            # loose either way
            assert obj.model_extra["scale"] == pytest.approx(1.0, abs=0.006)


def test_camera_rotation_in_the_model_levels_init_table(tmp_path):
    scene = write_scene(tmp_path / "scene", camera_rotation_deg=2.5)
    sup = support_residual(load_input(scene), G, np.radians(0.3))
    params = get_effect("camera_rotation").fit(Residuals(support=sup)).params
    assert np.degrees(np.arccos(sup.normal @ [0, 0, 1])) == pytest.approx(2.5, abs=0.2)
    _set_model(scene, {"effects": {"camera_rotation": params}})
    run_stage(get_stage("init"), scene)
    normal = np.asarray(read_state(scene / "init").support.normal)
    assert np.degrees(np.arccos(normal @ [0, 0, 1])) < 0.1
    # input/camera.json still holds the declared pose
    declared = json.loads((scene / "input" / "camera.json").read_text())["world_from_camera"]
    assert np.allclose(load_input(scene).camera.world_from_camera, declared)


# ---- state level: physopt, export ----------------------------------------------------------

def test_state_effects_reach_physopt_and_the_exported_scene(tmp_path):
    scene = write_init_state(tmp_path / "scene", [box(1, (0.08, 0.06, 0.05), (0, 0, 0.025)),
                                                  box(2, (0.05, 0.05, 0.05), (0.15, 0, 0.025))])
    _set_model(scene, {"effects": {"table_tilt": TILT, "com_offset": COM,
                                   "friction": FRICTION}})
    physopt = get_stage("physopt")
    run_stage(physopt, scene, build_options(physopt, None, {"use_diffsim": False,
                                                            "max_rounds": 0}))
    state = read_state(scene / "physopt")
    assert state.object(1).com_in_object == COM["objects"]["1"]["com_in_object_m"]
    assert state.object(1).friction == pytest.approx(0.35)
    np.testing.assert_allclose(state.support.normal, TILT["normal_world"])

    run_stage(get_stage("export"), scene)
    exported = json.loads((scene / "export" / "scene.json").read_text())
    assert exported["gravity"] == pytest.approx(list(G))  # a tilted table keeps gravity
    np.testing.assert_allclose(exported["support"]["normal"], TILT["normal_world"])
    up = -np.asarray(exported["gravity"]) / 9.81
    assert np.degrees(np.arccos(up @ exported["support"]["normal"])) == pytest.approx(2.0, abs=1e-3)
    objs = {o["id"]: o for o in exported["objects"]}
    np.testing.assert_allclose(objs[1]["com_in_object"], COM["objects"]["1"]["com_in_object_m"])
    assert objs[1]["friction"] == pytest.approx(0.35)
    assert objs[2]["friction"] == pytest.approx(read_state(scene / "physopt").object(2).friction)


def test_model_hash_covers_only_the_levels_a_stage_applies():
    model = with_effect({}, "com_offset", COM)
    assert model_part(model, {"input"}) == {}
    assert set(model_part(model, {"state"})) == {"com_offset"}
    manifest = Manifest()
    assert model_hashes(get_stage("export"), manifest) == {}  # no model: no extra key
    manifest.model = model
    assert model_hashes(get_stage("init"), manifest) == {}
    # export applies both levels: the state's effects, and the input's for its observation check
    assert list(model_hashes(get_stage("export"), manifest)) == ["manifest.model[input,state]"]
    manifest.model = {"effects": {"gremlins": {}}}
    assert model_hashes(get_stage("init"), manifest)  # unknown: counts for every level
    with pytest.raises(UnknownEffectError) as err:
        corrected_state(None, manifest.model)  # type: ignore[arg-type]
    assert isinstance(err.value, R2SError) and "gremlins" in str(err.value)


# ---- r2s run ---------------------------------------------------------------------------------

@pytest.mark.slow
def test_r2s_run_reruns_exactly_the_stages_the_model_changes(tmp_path):
    scene = write_scene(tmp_path / "scene", with_ball=False)
    first = _run(scene, overrides=FAST)
    assert _ran(first) == ["init", "graph", "geomopt", "physopt", "export"]
    assert _ran(_run(scene)) == []

    # a state-level effect: physopt and export, nothing before them
    _set_model(scene, with_effect({}, "com_offset", COM))
    export, manifest = get_stage("export"), load_manifest(scene / "manifest.json")
    options = build_options(export, manifest.stages["export"].options, {})
    assert staleness(export, ScenePaths(scene), options, manifest) == "model changed"
    stamps = {k: v.started_at for k, v in load_manifest(scene / "manifest.json").stages.items()}
    second = _run(scene)
    assert _ran(second) == ["physopt", "export"]
    exported = json.loads((scene / "export" / "scene.json").read_text())
    com = {o["id"]: o["com_in_object"] for o in exported["objects"]}[1]
    np.testing.assert_allclose(com, COM["objects"]["1"]["com_in_object_m"])
    after = load_manifest(scene / "manifest.json").stages
    for name in ("init", "graph", "geomopt"):
        assert after[name].started_at == stamps[name]
    assert _ran(_run(scene)) == []

    # the same model written again (diagnose composing an equal fit): nothing
    _set_model(scene, with_effect(load_manifest(scene / "manifest.json").model, "com_offset", COM))
    assert _ran(_run(scene)) == []

    # an input-level effect: init and everything that reads its result
    input_before = snapshot(scene / "input")
    _set_model(scene, with_effect(load_manifest(scene / "manifest.json").model, "depth_scale",
                                  {"scale": 1.01, "offset_m": 0.0}))
    assert _ran(_run(scene)) == ["init", "graph", "geomopt", "physopt", "export"]
    assert _ran(_run(scene)) == []
    assert snapshot(scene / "input") == input_before
    exported = json.loads((scene / "export" / "scene.json").read_text())
    com = {o["id"]: o["com_in_object"] for o in exported["objects"]}[1]
    np.testing.assert_allclose(com, COM["objects"]["1"]["com_in_object_m"])
