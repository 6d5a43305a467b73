"""Measuring residuals on synthetic observations with a known cause, and the model hooks.

- prior scale from ray-cast depth of known shapes (box, cylinder, sphere) on a table,
  scaled by 1.03 -> the depth-scale fit gives 1.03 +- 0.005; unscaled -> no effect;
- the table normal of a camera declared 2.5 deg off -> 2.5 +- 0.2 deg;
- PyBullet: a half cylinder seen rocked 25 deg off its uniform-density rest pose ->
  the COM shift that balances it, on the right side; a struck box that slides further
  than the default friction allows -> its friction;
- the hooks other stages call (corrected_input / corrected_state).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from helpers_diagnose import input_scene, render
from r2s.diagnose.data import PhysicsModel, RegistrationData, Residuals
from r2s.diagnose.effects import get_effect
from r2s.diagnose.measure.interaction import Push, simulate_push
from r2s.diagnose.measure.observe import (ObjectModel, fit_quality, interaction_residual,
                                          physics_residual, support_residual, world_spec)
from r2s.diagnose.measure.physics import support_contacts
from r2s.diagnose.measure.scene_dir import struck_objects_rest
from r2s.scene_model import corrected_input, corrected_state, with_effect
from r2s.diagnose.stats.ranking import diagnose
from r2s.diagnose.effects import all_effects
from r2s.io.state import ObjectState, SceneState, SupportPlane

G = np.array([0.0, 0.0, -9.81])


def _prior_models(scene, r, pose_noise_m: float = 0.004) -> list[ObjectModel]:
    """Each object's exact prior at a slightly wrong pose (as init would leave it)."""
    rng = np.random.default_rng(3)
    out = []
    for i, mesh, pose in r["objects"]:
        p = r["tilt"] @ pose
        p = p.copy()
        p[:3, 3] += rng.normal(0.0, pose_noise_m, 3)
        p[:3, :3] = Rotation.from_rotvec(rng.normal(0.0, 0.02, 3)).as_matrix() @ p[:3, :3]
        out.append(ObjectModel(id=i, label=str(i), mesh=mesh, world_from_object=p,
                               prior_area_m2=float(mesh.area)))
    return out


@pytest.mark.parametrize("scale", [1.03, 0.97, 1.0])
def test_prior_scale_measures_the_depth_scale(scale):
    r = render(depth_scale=scale)
    scene = input_scene(depth_scale=scale)
    obs = [fit_quality(scene, m).scale_obs for m in _prior_models(scene, r)]
    for o in obs:
        assert o.scale == pytest.approx(scale, abs=0.006)
        assert o.fitness > 0.9
    res = Residuals(registration=RegistrationData(tuple(obs), scale_sigma=0.01))
    fit = get_effect("depth_scale").fit(res)
    assert fit.params["scale"] == pytest.approx(scale, abs=0.005)
    chosen = [c.effect for c in diagnose(res, all_effects()).chosen]
    assert chosen == ([] if scale == 1.0 else ["depth_scale"])


def test_table_normal_of_a_misdeclared_camera():
    scene = input_scene(camera_rotation_deg=2.5)
    sup = support_residual(scene, G, np.radians(0.3))
    fit = get_effect("camera_rotation").fit(Residuals(support=sup))
    assert fit.params["angle_deg"] == pytest.approx(2.5, abs=0.2)
    # the error was a turn about world x: the fitted correction turns back about x
    axis = np.asarray(fit.params["axis_world"])
    assert abs(axis[0]) > 0.99
    corrected = corrected_input(scene, {"effects": {"camera_rotation": fit.params}})
    level = support_residual(corrected, G, np.radians(0.3))
    assert np.degrees(np.arccos(level.normal @ [0, 0, 1])) < 0.05
    clean = support_residual(input_scene(), G, np.radians(0.3))
    assert np.degrees(np.arccos(clean.normal @ [0, 0, 1])) < 0.05


# ---- PyBullet -----------------------------------------------------------------------------

def _half_cylinder(radius: float = 0.04, length: float = 0.12) -> trimesh.Trimesh:
    """Axis along x, flat face up in the plane z = 0, curved side below."""
    a = np.linspace(np.pi, 2 * np.pi, 97)
    ring = np.stack([np.zeros_like(a), radius * np.cos(a), radius * np.sin(a)], axis=1)
    return trimesh.convex.convex_hull(np.vstack([ring - [length / 2, 0, 0],
                                                 ring + [length / 2, 0, 0]]))


def _box_at(x: float, y: float, size: float = 0.06) -> tuple[trimesh.Trimesh, np.ndarray]:
    pose = np.eye(4)
    pose[:3, 3] = [x, y, size / 2]
    return trimesh.creation.box((size, size, size)), pose


def test_contact_patch_of_a_box_is_its_footprint():
    mesh, pose = _box_at(0.1, 0.0)
    spec = world_spec([ObjectModel(1, "box", mesh, pose, 1.0)], [0, 0, 0], [0, 0, 1], 0.8, None)
    pts = support_contacts(spec, np.array([0.0, 0.0, 1.0]))[0][1]
    assert np.abs(pts[:, 2]).max() < 2e-3
    np.testing.assert_allclose(pts[:, :2].min(axis=0), [0.07, -0.03], atol=2e-3)
    np.testing.assert_allclose(pts[:, :2].max(axis=0), [0.13, 0.03], atol=2e-3)


def test_com_offset_balances_a_rocked_half_cylinder():
    half = _half_cylinder()
    theta = np.radians(25.0)
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("x", theta).as_matrix()
    pose[2, 3] = 0.04  # the curved side touches z = 0 under the axis
    box, bpose = _box_at(0.2, 0.1)
    objs = [ObjectModel(1, "rocker", half, pose, 1.0), ObjectModel(2, "box", box, bpose, 1.0)]
    spec = world_spec(objs, [0, 0, 0], [0, 0, 1], 0.8, None)
    phys = physics_residual(spec, G, {1: True, 2: True}, 1.0, 0.01, np.radians(3.0), 4.0)
    assert np.degrees(phys.motion[1].angle_rad) > 10  # uniform density: it rocks back
    assert abs(phys.motion[1].rotation_rad[0]) > 0.9 * phys.motion[1].angle_rad  # about x
    d = diagnose(Residuals(physics=phys, support=support_of_plane()), all_effects())
    assert d.chosen and d.chosen[0].effect == "com_offset"
    shift = np.asarray(d.chosen[0].params["objects"]["1"]["shift_world_m"])
    # balance: the COM right above the line of contact (y = 0); uniform COM is at +y
    # (the smallest balancing shift reaches the edge of the facet the hull rests on)
    com_y = (pose[:3, :3] @ half.center_mass)[1]
    assert shift[1] == pytest.approx(-com_y, rel=0.25)
    assert abs(shift[0]) < 1e-3 and shift[2] == 0.0
    after = d.chosen[0].residuals_after.physics.motion[1]
    assert np.degrees(after.angle_rad) < 2.0


def support_of_plane():
    from r2s.diagnose.data import SupportData

    return SupportData(normal=np.array([0.0, 0.0, 1.0]), point=np.zeros(3))


def test_friction_from_a_struck_box():
    box, p1 = _box_at(0.0, 0.0)
    _, p2 = _box_at(0.0, 0.2)
    objs = [ObjectModel(1, "a", box, p1, 1.0, friction=0.8),
            ObjectModel(2, "b", box, p2, 1.0, friction=0.8)]
    spec = world_spec(objs, [0, 0, 0], [0, 0, 1], 0.8, None)
    push = Push(path_m=np.array([[-0.08, 0.0, 0.03], [-0.02, 0.0, 0.03]]), radius_m=0.01,
                speed_mps=0.6, settle_s=1.0)
    observed = simulate_push(spec, PhysicsModel().with_changes(friction={1: 0.3}), push)
    assert observed[1][0] > 0.05 and np.linalg.norm(observed[2]) < 2e-3
    phys = physics_residual(spec, G, {1: True, 2: True}, 1.0, 0.01, np.radians(3.0), 4.0)
    res = Residuals(physics=phys, interaction=interaction_residual(spec, phys.base, push,
                                                                   observed, 0.005))
    d = diagnose(res, all_effects())
    assert d.chosen[0].effect == "friction"
    mu = d.chosen[0].params["objects"]["1"]["friction"]
    assert mu == pytest.approx(0.3, rel=0.1)


def test_friction_is_fitted_on_a_resting_twin_when_the_geometric_state_moves():
    """The geometric state leans box 1 on a wedge-like tilt so that it slides by itself:
    measured on it, the push would measure the reconstruction and friction declines. The
    same push simulated on a resting twin (physopt's state in a real scene), with its own
    rest rollout, gives the friction back."""
    box, p1 = _box_at(0.0, 0.0)
    _, p2 = _box_at(0.0, 0.2)
    tilted = p1.copy()
    tilted[:3, :3] = Rotation.from_euler("y", 25, degrees=True).as_matrix()
    tilted[2, 3] = 0.045
    push = Push(path_m=np.array([[-0.08, 0.0, 0.03], [-0.02, 0.0, 0.03]]), radius_m=0.01,
                speed_mps=0.6, settle_s=1.0)
    twin = world_spec([ObjectModel(1, "a", box, p1, 1.0, friction=0.8),
                       ObjectModel(2, "b", box, p2, 1.0, friction=0.8)],
                      [0, 0, 0], [0, 0, 1], 0.8, None)
    observed = simulate_push(twin, PhysicsModel().with_changes(friction={1: 0.3}), push)
    geometric = world_spec([ObjectModel(1, "a", box, tilted, 1.0, friction=0.8),
                            ObjectModel(2, "b", box, p2, 1.0, friction=0.8)],
                           [0, 0, 0], [0, 0, 1], 0.8, None)
    phys = physics_residual(geometric, G, {1: True, 2: True}, 1.0, 0.01, np.radians(3.0), 4.0)
    assert 1 in phys.moving(phys.motion)
    on_geometric = interaction_residual(geometric, phys.base, push, observed, 0.005)
    fit = get_effect("friction").fit(Residuals(physics=phys, interaction=on_geometric))
    assert not fit.identifiable
    on_twin = interaction_residual(twin, phys.base, push, observed, 0.005, rest=phys,
                                   stage="physopt")
    assert on_twin.resting_ids == frozenset({1, 2})
    fit = get_effect("friction").fit(Residuals(physics=phys, interaction=on_twin))
    assert fit.params["objects"]["1"]["friction"] == pytest.approx(0.3, rel=0.1)
    # what interaction_source=auto reads: the struck box moves in the geometric state's
    # rollout, so the push goes to the resting twin; in the twin's own rollout it rests
    assert not struck_objects_rest(observed, phys, 0.005)
    twin_rest = physics_residual(twin, G, {1: True, 2: True}, 1.0, 0.01, np.radians(3.0), 4.0)
    assert struck_objects_rest(observed, twin_rest, 0.005)
    assert struck_objects_rest({1: np.zeros(3)}, phys, 0.005)  # nothing was struck


def test_a_friction_too_low_to_hold_a_box_on_a_slope_shows_in_the_static_rollout():
    """A box on a 20 deg slope (support friction 1, so the contact's is the box's) holds
    with friction 0.8 > tan 20 deg = 0.36 and slides with 0.3: the friction effect's
    prediction moves it in the static rollout too, not only in the push."""
    from r2s.diagnose.data import InteractionData
    from r2s.diagnose.effects.friction import with_friction

    tilt = Rotation.from_euler("y", 20, degrees=True).as_matrix()
    normal = tilt @ np.array([0.0, 0.0, 1.0])
    box = trimesh.creation.box((0.06, 0.06, 0.06))
    pose = np.eye(4)
    pose[:3, :3] = tilt
    pose[:3, 3] = 0.03 * normal + 1e-4 * normal
    spec = world_spec([ObjectModel(1, "a", box, pose, 1.0, friction=0.8)], [0, 0, 0], normal,
                      1.0, None)
    phys = physics_residual(spec, G, {1: True}, 1.0, 0.01, np.radians(3.0), 4.0)
    assert 1 not in phys.moving(phys.motion)
    inter = InteractionData(observed_m={1: np.zeros(3)}, predicted_m={1: np.zeros(3)},
                            simulate=lambda model: {1: np.zeros(3)})
    res = Residuals(physics=phys, interaction=inter)
    assert 1 not in with_friction(res, {1: 0.8}).physics.moving(phys.motion)
    slid = with_friction(res, {1: 0.3}).physics
    assert 1 in slid.moving(slid.motion)


# ---- hooks --------------------------------------------------------------------------------

def _state() -> SceneState:
    return SceneState(stage="init", support=SupportPlane(point=[0, 0, 0], normal=[0, 0, 1]),
                      objects=[ObjectState(id=3, label="a", mesh="meshes/3.glb",
                                           world_from_object=np.eye(4).tolist())])


def test_corrected_input_undoes_depth_scale():
    scene = input_scene(depth_scale=1.03)
    model = {"effects": {"depth_scale": {"scale": 1.03, "offset_m": 0.0}}}
    out = corrected_input(scene, model)
    ref = input_scene()
    ok = np.isfinite(ref.depth_m)
    np.testing.assert_allclose(out.depth_m[ok], ref.depth_m[ok], atol=1e-5)
    assert corrected_input(scene, {}) is scene


def test_corrected_state_applies_com_friction_and_table():
    model = {"effects": {
        "com_offset": {"objects": {"3": {"shift_world_m": [0.01, 0, 0],
                                         "offset_in_object_m": [0.01, 0, 0],
                                         "com_in_object_m": [0.01, 0.0, 0.02]}}},
        "friction": {"objects": {"3": {"friction": 0.35, "default_friction": 0.8}}},
        "table_tilt": {"angle_deg": 2.0, "axis_world": [1, 0, 0],
                       "normal_world": [0.0, -0.0349, 0.99939]},
    }}
    state = _state()
    out = corrected_state(state, model)
    assert out.objects[0].com_in_object == [0.01, 0.0, 0.02]
    assert out.objects[0].friction == 0.35
    assert out.support.normal == [0.0, -0.0349, 0.99939]
    assert state.objects[0].friction is None  # pure: the input is unchanged
    with pytest.raises(KeyError):
        corrected_state(state, {"effects": {"gremlins": {}}})


def test_camera_rotation_on_a_state_and_model_composition():
    eff = get_effect("camera_rotation")
    sup = support_residual(input_scene(camera_rotation_deg=2.5), G, np.radians(0.3))
    params = eff.fit(Residuals(support=sup)).params
    state = _state()
    state.support.normal = list(sup.normal)
    moved = corrected_state(state, {"effects": {"camera_rotation": params}},
                            include_input_effects=True)
    np.testing.assert_allclose(moved.support.normal, [0, 0, 1], atol=1e-9)
    model = with_effect({}, "camera_rotation", params)
    model = with_effect(model, "camera_rotation", params)
    assert model["effects"]["camera_rotation"]["angle_deg"] == pytest.approx(
        2 * params["angle_deg"], rel=1e-6)
