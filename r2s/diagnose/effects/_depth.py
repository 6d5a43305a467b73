"""Shared implementation of the depth-bias effects (scale, offset, both)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from r2s.diagnose.data import Residuals
from r2s.diagnose.effects._depth_model import (corrected_registration, corrected_support, correct_depth,
                                      fit_bias)
from r2s.diagnose.effects.base import Effect, EffectFit, make_fit, not_identifiable
from r2s.io.input_scene import InputScene

SIGNATURE = (
    "Priors of known (metric) size register to the observation with a common scale "
    "different from 1 across objects (depth scale), or with a scale that falls off as "
    "1/depth (depth offset); ICP fits are otherwise good. A scale keeps the table's "
    "normal; an offset turns it by a predictable amount (near points move by a larger "
    "share of their depth). Fit: weighted least squares of log(prior scale) against the "
    "bias model s + o s / (z - o) over the objects' observed depths z."
)


class DepthBiasEffect(Effect):
    """``z_observed = s * z_true + o``; which of ``s``, ``o`` are free is per instance."""

    level = "input"
    evidence_block = "registration"
    interacts_with = frozenset({"camera_rotation", "table_tilt", "lens_distortion"})

    def __init__(self, name: str, fit_scale: bool, fit_offset: bool, preference: int):
        self.name = name
        self.fit_scale = fit_scale
        self.fit_offset = fit_offset
        self.n_params = int(fit_scale) + int(fit_offset)
        self.preference = preference
        self.signature = SIGNATURE

    def fit(self, residuals: Residuals) -> EffectFit:
        reg = residuals.registration
        if reg is None or len(reg.used()) < self.n_params + 1:
            return not_identifiable(self.name, residuals,
                                    f"needs at least {self.n_params + 1} objects with a metric "
                                    "prior registered to the observation")
        scale, offset = fit_bias(reg, self.fit_scale, self.fit_offset)
        after = replace(residuals, registration=corrected_registration(reg, scale, offset))
        if residuals.support is not None:
            after = replace(after, support=corrected_support(residuals.support, scale, offset))
        params = {"scale": scale, "offset_m": offset}
        size, unit = (scale, "") if self.fit_scale else (offset, "m")
        return make_fit(self.name, residuals, after, params, self.n_params, size, unit,
                        note=self.describe(params))

    def apply_to_input(self, scene: InputScene, params: dict) -> InputScene:
        s = float(params.get("scale", 1.0))
        o = float(params.get("offset_m", 0.0))
        return replace(scene, depth_m=correct_depth(scene.depth_m, s, o).astype(np.float32))

    def compose(self, old: dict, new: dict) -> dict:
        # (z - o0)/s0 then (. - o1)/s1  ==  (z - (o0 + o1 s0)) / (s0 s1)
        s0, o0 = float(old.get("scale", 1.0)), float(old.get("offset_m", 0.0))
        s1, o1 = float(new.get("scale", 1.0)), float(new.get("offset_m", 0.0))
        return {"scale": s0 * s1, "offset_m": o0 + o1 * s0}

    def describe(self, params: dict) -> str:
        return (f"depth observed = {params.get('scale', 1.0):.4f} * true "
                f"{params.get('offset_m', 0.0) * 1000:+.1f} mm")
