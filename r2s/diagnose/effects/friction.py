"""Effect ``friction``: an object's friction differs from the default.

A static scene at rest says almost nothing about friction (any friction above the
slope's tangent holds it), so this effect is fitted only from an observed interaction
(``input/interaction/``): a pushed object that slides further or less far than predicted.
Without one it is reported as not identifiable instead of fitting noise. One parameter per
object whose friction is changed.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.optimize import minimize_scalar

from r2s.diagnose.stats.blocks import blocks_of, interaction_block, total_sse
from r2s.diagnose.data import InteractionData, PhysicsModel, Residuals
from r2s.diagnose.effects.base import EffectFit, PerObjectEffect, make_fit, not_identifiable

FRICTION_RANGE = (0.05, 2.5)
"""Search range of a body's friction coefficient."""
MAX_TURN_MISMATCH_DEG = 30.0
"""An object whose up direction the simulated push tilts this much more (or less) than it
was seen to tilt tumbles where it slid (or the reverse): its push says nothing about
friction."""


class Friction(PerObjectEffect):
    name = "friction"
    n_params = 1
    level = "state"
    preference = 40
    signature = (
        "In an observed push, an object moves further (less friction) or less far (more "
        "friction) than the simulation with the default friction predicts, while the "
        "static scene is consistent. Fit: per object, the friction coefficient that "
        "makes the simulated push match the observed displacements (1-D search in log "
        "friction), kept when it explains more than its parameter costs; only for objects "
        "that rest in a rollout without the push of the state the push is simulated on "
        "(geomopt's, with the default frictions, when the struck objects rest there; else "
        "physopt's when it ran; else the push measures the reconstruction), and whose "
        "simulated push tilts them about as much as they were seen to tilt (no flip where "
        "they slid)."
    )

    def fit(self, residuals: Residuals) -> EffectFit:
        inter = residuals.interaction
        if inter is None or not inter.observed_m:
            return not_identifiable(
                self.name, residuals,
                "no observed interaction (input/interaction/): friction is not identifiable "
                "from one static image")
        if inter.simulate is None or residuals.physics is None:
            return not_identifiable(self.name, residuals, "the push cannot be simulated")
        n_obs = sum(b.n for b in blocks_of(residuals).values())
        penalty = float(np.log(max(n_obs, 2)))
        base_sse = total_sse(blocks_of(residuals))
        phys = residuals.physics
        at_rest = (inter.resting_ids.__contains__ if inter.resting_ids is not None
                   else lambda i: i not in phys.moving(phys.motion))
        resting = [i for i in moved_objects(inter)
                   if at_rest(i) and (i not in phys.objects or phys.objects[i].geometry_ok)]
        if not resting:
            return not_identifiable(
                self.name, residuals,
                "the pushed objects do not rest in the static rollout (or fit their points "
                "badly): the simulated push would measure the reconstruction, not friction")
        trials, unlike = [], []
        for obj_id in resting:
            mu = fit_one(residuals, obj_id)
            if not same_kind_of_motion(inter, phys.base, obj_id, mu):
                unlike.append(obj_id)
                continue
            after = with_friction(residuals, {obj_id: mu})
            trials.append((base_sse - total_sse(blocks_of(after)), obj_id, mu, after))
        if not trials and unlike:
            return not_identifiable(
                self.name, residuals,
                "even with its best friction the simulated push tilts the pushed object "
                f"more than {MAX_TURN_MISMATCH_DEG:.0f} degrees unlike the observed one (one "
                "tumbles, the other slides): it measures the reconstructed shape, not "
                "friction")
        if not trials:
            return not_identifiable(self.name, residuals, "no object moved in the push")
        trials.sort(key=lambda t: -t[0])
        kept = {t[1]: t[2] for t in trials if t[0] > penalty} or {trials[0][1]: trials[0][2]}
        after = trials[0][3] if len(kept) == 1 else with_friction(residuals, kept)
        default = {i: residuals.physics.objects[i].friction for i in kept
                   if i in residuals.physics.objects}
        params = {"objects": {str(i): {"friction": float(mu),
                                       "default_friction": float(default.get(i, np.nan))}
                              for i, mu in kept.items()}}
        size = float(next(iter(kept.values()))) if len(kept) == 1 else \
            float(max(kept.values(), key=lambda m: abs(np.log(m))))
        return make_fit(self.name, residuals, after, params, self.n_params * len(kept), size,
                        "", note=self.describe(params))

    def apply_entry(self, obj, entry: dict) -> None:
        obj.friction = float(entry["friction"])

    def describe(self, params: dict) -> str:
        parts = [f"object {i}: friction {e['friction']:.2f}"
                 for i, e in params.get("objects", {}).items()]
        return "; ".join(parts) or "no friction change"


def same_kind_of_motion(inter: InteractionData, base: PhysicsModel, obj_id: int,
                        friction: float) -> bool:
    """The tilt of ``obj_id``'s up direction over the push simulated with ``friction``
    within ``MAX_TURN_MISMATCH_DEG`` of the observed one (True when either is not known)."""
    seen = inter.observed_tilt_rad.get(obj_id)
    if seen is None or inter.simulate_motion is None:
        return True
    motion = inter.simulate_motion(base.with_changes(friction={obj_id: friction}))
    if obj_id not in motion:
        return True
    tilt = motion[obj_id].tilt_rad(-np.asarray(base.gravity))
    return abs(np.degrees(seen - tilt)) <= MAX_TURN_MISMATCH_DEG


def moved_objects(inter: InteractionData, sigmas: float = 2.0) -> list[int]:
    """Objects that moved clearly in the observation or in the prediction."""
    out = []
    for obj_id, obs in inter.observed_m.items():
        pred = inter.predicted_m.get(obj_id, np.zeros(3))
        if max(np.linalg.norm(obs), np.linalg.norm(pred)) > sigmas * inter.sigma_m:
            out.append(obj_id)
    return sorted(out)


def with_friction(residuals: Residuals, friction: dict) -> Residuals:
    """The residuals predicted with the frictions ``friction`` (id -> coefficient): the
    push, and the static rollout too (a lower friction can set a leaning object sliding at
    rest, which then counts against the fit instead of surfacing in the next round as a
    COM offset)."""
    phys = residuals.physics
    model = phys.base.with_changes(friction=friction)
    inter = residuals.interaction
    physics = (phys.with_motion(model, phys.simulate(model)) if phys.simulate is not None
               else replace(phys, base=model))
    return replace(residuals, interaction=inter.with_prediction(inter.simulate(model)),
                   physics=physics)


def fit_one(residuals: Residuals, obj_id: int) -> float:
    """The friction of ``obj_id`` that best reproduces the observed push (others fixed)."""
    inter, phys = residuals.interaction, residuals.physics

    def cost(log_mu: float) -> float:
        model = phys.base.with_changes(friction={obj_id: float(np.exp(log_mu))})
        return interaction_block(inter.with_prediction(inter.simulate(model))).sse

    lo, hi = np.log(FRICTION_RANGE[0]), np.log(FRICTION_RANGE[1])
    grid = np.linspace(lo, hi, 7)
    costs = [cost(g) for g in grid]
    k = int(np.argmin(costs))
    a, b = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    sol = minimize_scalar(cost, bounds=(a, b), method="bounded", options={"xatol": 0.02})
    best = sol.x if sol.fun <= costs[k] else grid[k]
    return float(np.exp(best))


EFFECT = Friction()
