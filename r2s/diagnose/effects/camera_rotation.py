"""Effect ``camera_rotation``: the declared camera rotation is off, so gravity is not -z.

The true table is level; an error in the declared ``world_from_camera`` rotation turns the
whole observed world about the camera centre. Only the part of the error that tilts the
table is observable (2 parameters: angle and horizontal axis); a turn about the vertical
changes nothing physical and is not fitted.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from r2s.diagnose.data import Residuals
from r2s.diagnose.effects.base import Effect, EffectFit, make_fit, not_identifiable
from r2s.diagnose.effects._gravity import angle_axis, correction_to_level
from r2s.io.input_scene import Camera, InputScene
from r2s.io.state import SceneState


class CameraRotation(Effect):
    name = "camera_rotation"
    n_params = 2
    level = "input"
    preference = 19
    penalty = 0.0
    interacts_with = frozenset({"depth_scale", "depth_offset", "depth_bias"})
    signature = (
        "The support plane's normal, fitted in the declared world frame, is tilted away "
        "from the declared up by a few degrees, and in the rollout objects move downhill "
        "(roll or slide the same way) under the declared gravity but rest under gravity "
        "perpendicular to the table (only objects whose neighbours rest too count: a "
        "collapsing neighbour is no evidence about gravity). Fit: the smallest rotation "
        "about the camera centre that levels the fitted table."
    )

    def fit(self, residuals: Residuals) -> EffectFit:
        sup = residuals.support
        if sup is None:
            return not_identifiable(self.name, residuals, "no support plane was fitted")
        corr = correction_to_level(sup.up, sup.normal, sup.camera_center)
        after = level_world(residuals, corr)
        angle, axis = angle_axis(corr)
        params = {"angle_deg": angle, "axis_world": axis.tolist(),
                  "world_correction": corr.tolist(),
                  "pivot_world_m": np.asarray(sup.camera_center, dtype=float).tolist()}
        return make_fit(self.name, residuals, after, params, self.n_params, angle, "deg",
                        note=self.describe(params))

    def apply_to_camera(self, camera: Camera, params: dict) -> Camera:
        corr = np.asarray(params["world_correction"], dtype=np.float64)
        return Camera(K=camera.K, world_from_camera=corr @ camera.world_from_camera,
                      width=camera.width, height=camera.height)

    def apply_to_input(self, scene: InputScene, params: dict) -> InputScene:
        corr = np.asarray(params["world_correction"], dtype=np.float64)
        camera = self.apply_to_camera(scene.camera, params)
        objects = [o if o.world_from_prior is None else
                   replace(o, world_from_prior=corr @ o.world_from_prior)
                   for o in scene.objects]
        before = (np.eye(4) if scene.corrected_from_declared is None
                  else np.asarray(scene.corrected_from_declared, dtype=np.float64))
        return replace(scene, camera=camera, objects=objects,
                       corrected_from_declared=corr @ before)

    def apply_to_state(self, state: SceneState, params: dict) -> SceneState:
        return transform_state(state, np.asarray(params["world_correction"], dtype=np.float64))

    def compose(self, old: dict, new: dict) -> dict:
        corr = np.asarray(new["world_correction"]) @ np.asarray(old["world_correction"])
        angle, axis = angle_axis(corr)
        return {"angle_deg": angle, "axis_world": axis.tolist(), "world_correction": corr.tolist(),
                "pivot_world_m": new.get("pivot_world_m", old.get("pivot_world_m"))}

    def describe(self, params: dict) -> str:
        ax = np.round(params.get("axis_world", [0, 0, 1]), 3).tolist()
        return f"declared camera rotation off by {params.get('angle_deg', 0.0):.2f} deg about {ax}"


def level_world(residuals: Residuals, corr: np.ndarray) -> Residuals:
    """Residuals predicted when gravity is taken perpendicular to the fitted table.

    Everything stays in the current frame; only gravity turns (``R^T g``), which is the
    same physics as turning the world by ``corr`` under the declared gravity.
    """
    sup = residuals.support
    rot = corr[:3, :3]
    out = residuals
    if sup is not None:
        # the true table passes through the true origin, which the declared world holds at
        # corr^-1 (0): a rotation about the camera keeps the table's distance from it
        anchor = np.linalg.inv(corr) @ np.append(np.asarray(sup.anchor_world, dtype=float), 1.0)
        out = replace(out, support=replace(sup, up=rot.T @ np.asarray(sup.up, dtype=float),
                                           model_normal=None, anchor_world=anchor[:3]))
    phys = residuals.physics
    if phys is not None and phys.stage != "init":
        # init's state is each object's raw registration: one that moves under one gravity
        # and rests under the other says its pose is a little off, not where down is (as
        # for com_offset); the geometric evidence (the table) decides there
        model = phys.base.with_changes(gravity=rot.T @ phys.base.gravity)
        motion = phys.simulate(model) if phys.simulate is not None else phys.motion
        motion = slope_explained(phys, motion)
        out = replace(out, physics=phys.with_motion(model, motion))
        inter = residuals.interaction
        if inter is not None and inter.simulate is not None:
            out = replace(out, interaction=inter.with_prediction(inter.simulate(model)))
    return out


def slope_explained(phys, level_motion: dict) -> dict:
    """The rollout under level gravity, credited only where the slope alone explains the
    difference. An object that moves under both gravities, or touches one that does, moves
    because the reconstruction is imperfect (a collapsing neighbour, a wrong shape): no
    evidence either way, it keeps its declared-gravity motion. The rest count both ways:
    moving under the declared gravity and resting when levelled is evidence for the camera,
    resting under the declared gravity and moving when levelled evidence for a tilted table."""
    unexplained = phys.moving(level_motion) & phys.moving(phys.motion)
    out = {}
    for obj_id, m in level_motion.items():
        obj = phys.objects.get(obj_id)
        touched = set(obj.neighbours) if obj is not None else set()
        out[obj_id] = phys.motion.get(obj_id, m) if ({obj_id} | touched) & unexplained else m
    return out


def transform_state(state: SceneState, world_correction: np.ndarray) -> SceneState:
    """The state moved rigidly by ``world_correction`` (4, 4); gravity is kept."""
    t = np.asarray(world_correction, dtype=np.float64)
    new = state.model_copy(deep=True)
    for obj in new.objects:
        obj.world_from_object = (t @ obj.pose).tolist()
    sup = new.support
    sup.point = (t[:3, :3] @ np.asarray(sup.point) + t[:3, 3]).tolist()
    sup.normal = (t[:3, :3] @ np.asarray(sup.normal)).tolist()
    return new


EFFECT = CameraRotation()
