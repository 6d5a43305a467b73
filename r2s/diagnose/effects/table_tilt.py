"""Effect ``table_tilt``: the table is not level; gravity is as declared.

From one image this looks exactly like a camera rotation error on the support residual
(the fitted normal is tilted from the declared up). The two differ only in physics: with a
tilted table the reconstruction rests under the declared gravity; with a wrong camera it
rests only under gravity perpendicular to the table. When the rollout cannot tell them
apart, this one is preferred: it keeps the declared camera and changes no pose.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from r2s.diagnose.stats.blocks import tilt_vector
from r2s.diagnose.data import Residuals
from r2s.diagnose.effects.base import Effect, EffectFit, make_fit, not_identifiable
from r2s.diagnose.effects._gravity import angle_axis, correction_to_level
from r2s.io.state import SceneState


SAME_PLANE_DEG = 0.3
"""A state whose support normal is within this angle of the fitted one (the support
residual's default noise level) already has the tilt; applying the effect keeps it."""


class TableTilt(Effect):
    name = "table_tilt"
    n_params = 2
    level = "state"
    preference = 20
    penalty = float(2.0 * np.log(4.0))
    """The prior (docs/diagnose.md): a few degrees between the fitted table and the
    declared vertical is a camera extrinsic error 4 times in 5 and a tilted table once,
    so ``table_tilt`` carries ``-2 ln(1/4)`` = 2.77 BIC units against ``camera_rotation``."""
    signature = (
        "The support plane's normal is tilted away from the declared up, while the "
        "reconstruction rests under the declared gravity (no common downhill motion). "
        "Fit: the fitted table normal (tilt angle and axis); gravity is unchanged."
    )

    def fit(self, residuals: Residuals) -> EffectFit:
        sup = residuals.support
        if sup is None:
            return not_identifiable(self.name, residuals, "no support plane was fitted")
        normal = np.asarray(sup.normal, dtype=np.float64)
        normal = normal / np.linalg.norm(normal)
        after = replace(residuals, support=replace(sup, model_normal=normal))
        angle, axis = angle_axis(correction_to_level(normal, sup.up, np.zeros(3)))
        params = {"angle_deg": angle, "axis_world": axis.tolist(), "normal_world": normal.tolist()}
        return make_fit(self.name, residuals, after, params, self.n_params, angle, "deg",
                        note=self.describe(params))

    def apply_to_state(self, state: SceneState, params: dict) -> SceneState:
        new = state.model_copy(deep=True)
        fitted = np.asarray(params["normal_world"], dtype=np.float64)
        apart_deg = np.degrees(np.linalg.norm(tilt_vector(state.support.normal, fitted)))
        if apart_deg <= SAME_PLANE_DEG:
            # the state's plane (fitted by init to the same table pixels) holds the tilt
            # already: swapping it for another estimate within the noise changes nothing
            # physical, but a later optimisation would start from a different point
            return new
        new.support.normal = [float(x) for x in fitted]
        new.support.tilted = True  # type: ignore[attr-defined]  (extra key: keep it tilted)
        return new

    def describe(self, params: dict) -> str:
        return f"table tilted {params.get('angle_deg', 0.0):.2f} deg from level"


EFFECT = TableTilt()
