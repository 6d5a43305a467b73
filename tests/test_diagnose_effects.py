"""Each effect's fit on small hand-made residuals with a known parameter, and the ranking.

The physical residuals here come from analytic stand-ins for the rollout (a toppling
object turns with the torque of its off-support COM; a push slides an object the further
the lower its friction), so every fitted number has an exact expected value.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from r2s.diagnose.stats.blocks import blocks_of, tilt_vector, total_n, total_sse
from r2s.diagnose.data import (InteractionData, Motion, PhysicsData, PhysicsModel, PhysObject,
                               RegistrationData, Residuals, ScaleObs, SupportData)
from r2s.diagnose.effects import all_effects, get_effect
from r2s.diagnose.stats.ranking import diagnose
from r2s.diagnose.effects._wrench import balancing_com_shift, nearest_in_hull_2d, toppling_direction

G = np.array([0.0, 0.0, -9.81])


def _registration(scale: float, seed: int = 0, n: int = 6, noise: float = 0.003,
                  offset_m: float = 0.0) -> RegistrationData:
    rng = np.random.default_rng(seed)
    objs = []
    for i in range(n):
        z = float(rng.uniform(0.5, 1.2))
        s = (scale + offset_m * scale / (z - offset_m)) * np.exp(rng.normal(0.0, noise))
        objs.append(ScaleObs(id=i + 1, scale=float(s), depth_m=z, fitness=0.95, rmse_m=0.001))
    return RegistrationData(tuple(objs), scale_sigma=0.01)


def _support(tilt_deg: float, axis=(1.0, 0.0, 0.0), seed: int = 0,
             noise_deg: float = 0.03) -> SupportData:
    rng = np.random.default_rng(seed)
    rot = Rotation.from_rotvec(np.radians(tilt_deg) * np.asarray(axis, dtype=float))
    jitter = Rotation.from_rotvec(np.radians(noise_deg) * rng.normal(size=3))
    normal = (jitter * rot).apply([0.0, 0.0, 1.0])
    return SupportData(normal=normal, point=np.zeros(3), camera_center=np.array([0.5, -0.4, 0.5]),
                       n_points=20000)


# ---- a hand-made physical world: boxes at rest, one object on a line contact ----------

LINE_CONTACT = np.array([[0.0, -0.03, 0.0], [0.0, 0.03, 0.0]])
"""Object 7 rests on a line along y through x = 0 (a cylinder lying on its side)."""


def _toppling_sim(com_x: float, gravity_tilt: np.ndarray | None = None):
    """Rollout stand-in: object 7 turns about y by 40 rad per metre its COM is off the line;
    objects 1-3 rest (up to noise), unless gravity is tilted, then they all slide."""

    def simulate(model: PhysicsModel) -> dict:
        shift = np.asarray(model.com_shift_world_m.get(7, np.zeros(3)))
        off = com_x + shift[0]
        g = np.asarray(model.gravity)
        downhill = g - (g @ np.array([0, 0, -1.0])) * np.array([0, 0, -1.0])
        out = {}
        for i in (1, 2, 3):
            out[i] = Motion(translation_m=0.02 * downhill + np.array([1e-4 * i, 0, 0]),
                            rotation_rad=np.zeros(3))
        angle = 40.0 * off if abs(off) > 5e-4 else 0.0
        out[7] = Motion(translation_m=np.array([0.5 * angle * 0.04, 0.0, 0.0]),
                        rotation_rad=np.array([0.0, angle, 0.0]))
        return out

    return simulate


def _physics(com_x: float) -> PhysicsData:
    sim = _toppling_sim(com_x)
    base = PhysicsModel(gravity=G)
    objects = {i: PhysObject(id=i, com_world=np.array([0.1 * i, 0.2, 0.03]), radius_m=0.05)
               for i in (1, 2, 3)}
    objects[7] = PhysObject(id=7, com_world=np.array([com_x, 0.0, 0.04]),
                            support_contacts_world=LINE_CONTACT, radius_m=0.06)
    return PhysicsData(base=base, objects=objects, motion=sim(base), simulate=sim)


# ---- registry ---------------------------------------------------------------------------

def test_catalogue_has_every_required_effect_with_a_signature():
    cat = all_effects()
    for name in ("depth_scale", "depth_offset", "depth_bias", "camera_rotation", "table_tilt",
                 "com_offset", "friction"):
        assert name in cat
        assert cat[name].name == name and cat[name].n_params >= 1
        assert len(cat[name].signature) > 40
    with pytest.raises(KeyError):
        get_effect("no_such_effect")


# ---- depth bias -----------------------------------------------------------------------

def test_depth_scale_fit_recovers_the_scale():
    fit = get_effect("depth_scale").fit(Residuals(registration=_registration(1.03)))
    assert fit.params["scale"] == pytest.approx(1.03, abs=0.005)
    assert fit.delta_bic < -10
    after = blocks_of(fit.residuals_after)["registration"]
    assert np.abs(after.values).max() < 0.012  # only the 0.3 % per-object noise is left


def test_depth_offset_fit_recovers_the_offset():
    reg = _registration(1.0, offset_m=0.02, noise=0.001)
    fit = get_effect("depth_offset").fit(Residuals(registration=reg))
    assert fit.params["offset_m"] == pytest.approx(0.02, abs=0.002)
    both = get_effect("depth_bias").fit(Residuals(registration=reg))
    assert both.params["offset_m"] == pytest.approx(0.02, abs=0.004)
    assert both.params["scale"] == pytest.approx(1.0, abs=0.004)


def test_depth_bias_compose_equals_applying_twice():
    eff = get_effect("depth_scale")
    old, new = {"scale": 1.02, "offset_m": 0.004}, {"scale": 0.99, "offset_m": -0.002}
    z = np.array([0.5, 0.8, 1.3])
    from r2s.diagnose.effects._depth_model import correct_depth

    twice = correct_depth(correct_depth(z, 1.02, 0.004), 0.99, -0.002)
    comp = eff.compose(old, new)
    np.testing.assert_allclose(correct_depth(z, comp["scale"], comp["offset_m"]), twice,
                               rtol=1e-12)


# ---- gravity not perpendicular to the table ---------------------------------------------

@pytest.mark.parametrize("axis", [(1.0, 0.0, 0.0), (0.6, 0.8, 0.0)])
def test_tilted_table_normal_fits_its_angle(axis):
    res = Residuals(support=_support(2.5, axis))
    for name in ("camera_rotation", "table_tilt"):
        fit = get_effect(name).fit(res)
        assert fit.params["angle_deg"] == pytest.approx(2.5, abs=0.2)
        assert fit.delta_bic < -10
        assert blocks_of(fit.residuals_after)["support"].sse < 1e-6
    corr = np.asarray(get_effect("camera_rotation").fit(res).params["world_correction"])
    # the correction takes the fitted normal to +z
    np.testing.assert_allclose(corr[:3, :3] @ res.support.normal, [0, 0, 1], atol=1e-9)
    # ... about the camera centre, which stays put
    c = res.support.camera_center
    np.testing.assert_allclose(corr[:3, :3] @ c + corr[:3, 3], c, atol=1e-12)


def test_physics_decides_between_camera_rotation_and_table_tilt():
    sup = _support(2.5)
    tilt_g = Rotation.from_rotvec(np.radians(2.5) * np.array([1.0, 0, 0])).apply([0, 0, -9.81])

    def sim(model: PhysicsModel) -> dict:  # objects slide unless gravity is normal to table
        g = np.asarray(model.gravity)
        along = g - (g @ -sup.normal) * -sup.normal
        return {i: Motion(0.5 * along, np.zeros(3)) for i in (1, 2, 3)}

    base = PhysicsModel(gravity=G)
    objs = {i: PhysObject(id=i, com_world=np.zeros(3)) for i in (1, 2, 3)}
    phys = PhysicsData(base=base, objects=objs, motion=sim(base), simulate=sim)
    d = diagnose(Residuals(support=sup, physics=phys), all_effects())
    assert d.chosen[0].effect == "camera_rotation"
    # at rest either way: the two are tied, and the prior (a camera error 4 times in 5)
    # names the camera, with the table tilt reported as the alternative
    still = PhysicsData(base=base, objects=objs,
                        motion={i: Motion(np.zeros(3), np.zeros(3)) for i in objs},
                        simulate=lambda m: {i: Motion(np.zeros(3), np.zeros(3)) for i in objs})
    d = diagnose(Residuals(support=sup, physics=still), all_effects())
    assert d.chosen[0].effect == "camera_rotation"
    assert set(d.rounds[0].ties) == {"table_tilt", "camera_rotation"}
    fits = {f.effect: f for f in d.rounds[0].fits}
    assert fits["camera_rotation"].delta_bic == pytest.approx(fits["table_tilt"].delta_bic)
    assert fits["table_tilt"].score == pytest.approx(fits["camera_rotation"].score
                                                     + 2.0 * np.log(4.0))

    # resting under the declared gravity, sliding under gravity normal to the table: the
    # physics outweighs the prior and names the tilted table
    def slides_when_levelled(model: PhysicsModel) -> dict:
        g = np.asarray(model.gravity)
        off = g - G
        return {i: Motion(0.5 * off, np.zeros(3)) for i in (1, 2, 3)}

    rests = PhysicsData(base=base, objects=objs, motion=slides_when_levelled(base),
                        simulate=slides_when_levelled)
    d = diagnose(Residuals(support=sup, physics=rests), all_effects())
    assert d.chosen[0].effect == "table_tilt"
    assert tilt_g[2] < 0


# ---- centre of mass ---------------------------------------------------------------------

def test_balancing_shift_on_line_and_area_contacts():
    shift = balancing_com_shift(np.array([0.02, 0.01, 0.05]), LINE_CONTACT, G)
    np.testing.assert_allclose(shift, [-0.02, 0.0, 0.0], atol=1e-9)
    square = np.array([[x, y, 0.0] for x in (-0.01, 0.01) for y in (-0.01, 0.01)])
    shift = balancing_com_shift(np.array([0.03, 0.0, 0.05]), square, G, margin_m=0.002)
    np.testing.assert_allclose(shift, [-0.022, 0.0, 0.0], atol=1e-9)
    assert not balancing_com_shift(np.array([0.005, 0.0, 0.05]), square, G).any()
    q, inside = nearest_in_hull_2d(np.array([[0.0, 0.0]]), np.array([0.01, 0.0]))
    assert not inside and np.allclose(q, 0.0)


def test_toppling_direction_stops_the_turn():
    # turning about +y under -z gravity: the COM is on the +x side; move it to -x
    np.testing.assert_allclose(toppling_direction(np.array([0.0, 0.3, 0.0]), G), [-1, 0, 0],
                               atol=1e-12)


def test_com_offset_fit_on_a_toppling_object():
    res = Residuals(physics=_physics(com_x=0.02), support=_support(0.0))
    fit = get_effect("com_offset").fit(res)
    entry = fit.params["objects"]["7"]
    shift = np.asarray(entry["shift_world_m"])
    assert shift[0] == pytest.approx(-0.02, abs=1e-3)
    assert abs(shift[1]) < 1e-3 and abs(shift[2]) < 1e-9
    assert fit.size == pytest.approx(0.02, rel=0.05)
    d = diagnose(res, all_effects())
    assert d.chosen[0].effect == "com_offset"
    assert fit.residuals_after.physics.motion[7].angle_rad == 0.0


def test_com_offset_prior_odds_count_once_per_shifted_object():
    """100:1 against per object: one shifted object costs 2 ln 100, two cost twice that,
    and the ranking scores a fit with it (the toppling object above, one shift)."""
    from dataclasses import replace

    from r2s.diagnose.stats.ranking import fit_effect

    effect = get_effect("com_offset")
    res = Residuals(physics=_physics(com_x=0.02), support=_support(0.0))
    fit = fit_effect(effect, res, effect.penalty)
    assert fit.penalty == pytest.approx(2.0 * np.log(100.0))
    assert fit.score == pytest.approx(fit.delta_bic + 2.0 * np.log(100.0))
    entry = fit.params["objects"]["7"]
    two = replace(fit, params={"objects": {"7": entry, "8": entry}})
    assert effect.prior_penalty(two, effect.penalty) == pytest.approx(4.0 * np.log(100.0))


def test_com_offset_on_a_reconstructed_state_is_reported_not_applied():
    """The same toppling object, its rollout marked as a reconstructed scene's (geomopt's
    state, no ``com_from_rollout``): the 2 cm shift is named in the note, not fitted."""
    from dataclasses import replace

    phys = replace(_physics(com_x=0.02), stage="geomopt", density_evidence=False)
    res = Residuals(physics=phys, support=_support(0.0))
    fit = get_effect("com_offset").fit(res)
    assert not fit.identifiable
    assert "object 7: COM 2.0 cm off" in fit.note and "not applied" in fit.note
    trusted = get_effect("com_offset").fit(
        replace(res, physics=replace(phys, density_evidence=True)))
    assert trusted.identifiable and trusted.size == pytest.approx(0.02, rel=0.05)


def test_com_offset_line_search_without_contacts_moves_the_right_way():
    phys = _physics(com_x=0.02)
    objects = dict(phys.objects)
    o = objects[7]
    objects[7] = PhysObject(id=7, com_world=o.com_world, radius_m=o.radius_m)
    res = Residuals(physics=PhysicsData(base=phys.base, objects=objects, motion=phys.motion,
                                        simulate=phys.simulate))
    shift = np.asarray(get_effect("com_offset").fit(res).params["objects"]["7"]["shift_world_m"])
    assert shift[0] < -0.01 and abs(shift[1]) < 1e-9


# ---- friction ---------------------------------------------------------------------------

def _push_world(mu_true: float) -> tuple[PhysicsData, InteractionData]:
    """Object 5 slides 6 cm * exp(-2 mu) along x after a push; object 6 is not touched."""

    def push(model: PhysicsModel) -> dict:
        mu = float(model.friction.get(5, 0.8))
        return {5: np.array([0.06 * np.exp(-2.0 * mu), 0.0, 0.0]), 6: np.zeros(3)}

    base = PhysicsModel(gravity=G)
    objs = {5: PhysObject(id=5, com_world=np.zeros(3), friction=0.8),
            6: PhysObject(id=6, com_world=np.ones(3), friction=0.8)}
    rest = {i: Motion(np.zeros(3), np.zeros(3)) for i in objs}
    phys = PhysicsData(base=base, objects=objs, motion=rest, simulate=lambda m: rest)
    observed = push(base.with_changes(friction={5: mu_true}))
    inter = InteractionData(observed_m=observed, predicted_m=push(base), simulate=push,
                            sigma_m=0.002)
    return phys, inter


def test_friction_fit_from_an_observed_push():
    phys, inter = _push_world(0.3)
    res = Residuals(physics=phys, interaction=inter)
    fit = get_effect("friction").fit(res)
    assert fit.params["objects"]["5"]["friction"] == pytest.approx(0.3, rel=0.03)
    assert "6" not in fit.params["objects"]
    assert diagnose(res, all_effects()).chosen[0].effect == "friction"


def test_friction_declines_when_the_simulated_push_tumbles_what_slid():
    """Seen to slide (2 degrees). A reconstruction that flips over (180 degrees) at any
    friction measures its shape: declined. One that flips only at high friction (a struck
    block tips when its base grips) but slides at the fitted 0.3: fitted as before."""
    from dataclasses import replace

    phys, inter = _push_world(0.3)

    def motion(flips_above: float):
        def simulate_motion(model: PhysicsModel) -> dict:
            d = inter.simulate(model)
            mu = float(model.friction.get(5, 0.8))
            turn = np.pi if mu > flips_above else np.radians(3.0)
            return {5: Motion(d[5], np.array([0.0, turn, 0.0])), 6: Motion(d[6], np.zeros(3))}
        return simulate_motion

    seen = {5: np.radians(2.0)}  # tilt of its up direction
    always = replace(inter, observed_tilt_rad=seen, simulate_motion=motion(0.0))
    fit = get_effect("friction").fit(Residuals(physics=phys, interaction=always))
    assert not fit.identifiable and "tilts" in fit.note
    grips = replace(inter, observed_tilt_rad=seen, simulate_motion=motion(0.5))
    fit = get_effect("friction").fit(Residuals(physics=phys, interaction=grips))
    assert fit.params["objects"]["5"]["friction"] == pytest.approx(0.3, rel=0.03)


def test_friction_is_not_identifiable_without_an_interaction():
    phys, _ = _push_world(0.3)
    fit = get_effect("friction").fit(Residuals(physics=phys))
    assert not fit.identifiable and "not identifiable" in fit.note
    assert fit.delta_bic == np.inf


# ---- ranking on clean data --------------------------------------------------------------

def test_no_effect_on_pure_noise():
    """Pure-noise residuals (half the modelled noise levels, about what clean scenes show):
    no effect may win, over many noise draws. (At exactly the modelled level BIC's own
    false-positive rate, a few per cent per 2-parameter effect, would show.)"""
    chosen = []
    for seed in range(40):
        rng = np.random.default_rng(100 + seed)
        rest = {i: Motion(rng.normal(0, 0.003, 3), rng.normal(0, 0.01, 3)) for i in (1, 2, 3, 7)}
        objs = {i: PhysObject(id=i, com_world=np.zeros(3),
                              support_contacts_world=LINE_CONTACT) for i in rest}
        phys = PhysicsData(base=PhysicsModel(gravity=G), objects=objs, motion=rest,
                           simulate=lambda m, rest=rest: rest)
        res = Residuals(registration=_registration(1.0, seed=seed, noise=0.005),
                        support=_support(0.0, seed=seed, noise_deg=0.15), physics=phys)
        d = diagnose(res, all_effects(), max_effects=2)
        chosen += [c.effect for c in d.chosen]
    assert chosen == []


def test_two_effects_are_found_one_after_the_other():
    res = Residuals(registration=_registration(0.97), support=_support(2.0))
    d = diagnose(res, all_effects(), max_effects=2)
    found = {c.effect: c for c in d.chosen}
    # without physics the tilt goes to the camera, by the prior
    assert len(found) == 2 and "depth_scale" in found and "camera_rotation" in found
    assert found["depth_scale"].size == pytest.approx(0.97, abs=0.005)
    assert found["camera_rotation"].size == pytest.approx(2.0, abs=0.2)
    assert d.sse_after < 0.05 * d.sse_before


def test_bic_bookkeeping():
    res = Residuals(registration=_registration(1.03))
    fit = get_effect("depth_scale").fit(res)
    b = blocks_of(res)
    assert fit.sse_before == pytest.approx(total_sse(b))
    assert fit.n_obs == total_n(b) == 6
    assert fit.delta_bic == pytest.approx(-fit.explained_sse + np.log(6))
    assert np.linalg.norm(tilt_vector([0, 0, 1], [0, np.sin(0.1), np.cos(0.1)])) == \
        pytest.approx(0.1)


def test_table_tilt_keeps_a_state_plane_that_already_has_the_tilt():
    """Applying the effect to a state whose support normal agrees with the fitted one
    within the support noise changes nothing (a rerun then reproduces the state exactly);
    a level state gets the fitted normal."""
    from r2s.io.state import SceneState, SupportPlane

    fit = get_effect("table_tilt").fit(Residuals(support=_support(2.5, (1.0, 0.0, 0.0))))
    fitted = np.asarray(fit.params["normal_world"])
    near = Rotation.from_rotvec(np.radians(0.1) * np.array([0.0, 1.0, 0.0])).apply(fitted)
    state = SceneState(stage="geomopt", support=SupportPlane(point=[0, 0, 0], normal=near.tolist()),
                       gravity=[0, 0, -9.81], objects=[])
    kept = get_effect("table_tilt").apply_to_state(state, fit.params)
    np.testing.assert_array_equal(kept.support.normal, state.support.normal)
    level = state.model_copy(update={"support": SupportPlane(point=[0, 0, 0], normal=[0, 0, 1])})
    tilted = get_effect("table_tilt").apply_to_state(level, fit.params)
    np.testing.assert_allclose(tilted.support.normal, fitted, atol=1e-12)
    angle = np.degrees(np.arccos(np.clip(np.asarray(tilted.support.normal) @ [0, 0, 1], -1, 1)))
    assert angle == pytest.approx(2.5, abs=0.2)
