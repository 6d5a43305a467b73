"""Shared implementation of the depth-bias effects (scale, offset, both)."""

from __future__ import annotations

from dataclasses import replace
from typing import Optional

import numpy as np
from scipy.stats import chi2

from r2s.diagnose.data import Residuals
from r2s.diagnose.effects._depth_model import (corrected_registration, corrected_support,
                                               correct_depth, fit_bias,
                                               offset_information_from_priors,
                                               offset_sigma_from_priors)
from r2s.diagnose.stats.noise import mixed_sampling_bar, null_registrations, sampling_bar
from r2s.diagnose.stats.table_height import height_evidence, with_height
from r2s.diagnose.stats.table_offset import (MAX_TABLE_OFFSET_M, TableOffsetEvidence,
                                             corrected_table, offset_evidence,
                                             with_measured_noise)
from r2s.diagnose.effects.base import Effect, EffectFit, make_fit, not_identifiable
from r2s.io.input_scene import InputScene

SIGNATURE = (
    "Priors of known (metric) size register to the observation with a common scale "
    "different from 1 across objects (depth scale), or with a scale that falls off as "
    "1/depth (depth offset); ICP fits are otherwise good. A scale keeps the table a plane "
    "with the same normal; an offset bends an obliquely seen table away from a plane "
    "(near points move by a larger share of their depth) and turns its normal. Fit: "
    "weighted least squares of log(prior scale) against the bias model s + o s / (z - o) "
    "over the objects' observed depths z, with the offset that makes the table flattest "
    "as one more observation of o (when the two agree)."
)

CONSISTENT_CHI2 = float(chi2.ppf(0.99, 1))
"""The table's offset and the priors' offset must agree within this (chi-square, 1 dof,
0.99 quantile: 6.63) for the table to count as evidence of the offset; otherwise the table
is bent by something else (reported by the structure test), or the priors' common size is
a depth scale that leaves the table flat, and only the priors speak. Measured on the
benchmark's scenes (docs/diagnose.md section 4a): 1 cm offset scenes at most 3.5, clean
scenes at most 2.0, 4 % scale scenes 3.2-17.8 (5 of 6 above)."""


class DepthBiasEffect(Effect):
    """``z_observed = s * z_true + o``; which of ``s``, ``o`` are free is per instance.

    Evidence: the prior scales (registration block) and, for an offset alone, the
    table's shape (:mod:`r2s.diagnose.stats.table_offset`) when the priors agree with it.
    ``depth_bias`` (scale and offset) uses the priors only: with the scale free they
    cannot tell the table's offset from a bend that has another cause. Every fit predicts
    the table's shape after it (so an offset that bends the table is scored by it)."""

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

    @property
    def quantities(self) -> frozenset:
        """The depth's scale and/or offset: ``depth_bias`` sets both that ``depth_scale``
        and ``depth_offset`` set one each."""
        return frozenset(q for q, fitted in (("depth_scale", self.fit_scale),
                                             ("depth_offset", self.fit_offset)) if fitted)

    def table_evidence(self, residuals: Residuals) -> tuple[Optional[TableOffsetEvidence], str]:
        """The table's offset evidence when it counts for this effect, and why not when
        it does not ("" when there is none to speak of)."""
        # with the scale free too, the priors cannot veto the table's offset (a scale
        # makes up for it at their depths): a bend from something else would be absorbed
        if not self.fit_offset or self.fit_scale or residuals.table_shape is None:
            return None, ""
        # at the scene's own tile scatter (pooled with the configured level)
        ev = offset_evidence(with_measured_noise(residuals.table_shape))
        if ev is None:
            return None, ""
        if abs(ev.offset_m) > MAX_TABLE_OFFSET_M:
            return None, (f"the table's shape asks for an offset of {ev.offset_m * 1000:+.0f} mm, "
                          f"beyond {MAX_TABLE_OFFSET_M * 1000:.0f} mm: not an offset")
        reg = residuals.registration
        if reg is not None and len(reg.used()) >= self.n_params + 1:
            _, o_p = fit_bias(reg, self.fit_scale, True)
            sig_p = offset_sigma_from_priors(reg, self.fit_scale, o_p)
            if np.isfinite(sig_p) and ((o_p - ev.offset_m) ** 2
                                       / (sig_p ** 2 + ev.sigma_m ** 2) > CONSISTENT_CHI2):
                return None, (f"the table's shape asks for {ev.offset_m * 1000:+.1f} mm, the "
                              f"priors for {o_p * 1000:+.1f} +- {sig_p * 1000:.1f} mm: they "
                              "disagree, the table is not used")
        return ev, ""

    def fit(self, residuals: Residuals) -> EffectFit:
        table, why_not = self.table_evidence(residuals)
        if table is None:
            fit = self.fit_with(residuals, None)
        else:
            # the table's part of the explained SSE at the noise level its evidence has;
            # the predicted residuals keep the configured level (what a rerun measures)
            measured = replace(residuals, table_shape=with_measured_noise(residuals.table_shape))
            fit = self.fit_with(measured, table)
            after = fit.residuals_after
            if after is not None and after.table_shape is not None:
                sigma0 = residuals.table_shape.sigma_m
                fit = replace(fit, residuals_after=replace(
                    after, table_shape=replace(after.table_shape, sigma_m=sigma0)))
        if why_not:
            fit = replace(fit, note=f"{fit.note}; {why_not}")
        return fit

    def fit_with(self, residuals: Residuals, table: Optional[TableOffsetEvidence]) -> EffectFit:
        """The fit with ``table`` as the table's evidence (None: the priors alone)."""
        reg = residuals.registration
        n_reg = len(reg.used()) if reg is not None else 0
        height = height_evidence(residuals.support)
        # the table's shape tells the offset, never the scale; its height (where the
        # declared world gives it) tells either one: one of them alone needs no prior
        if self.n_params == 1 and (height is not None or (table is not None
                                                          and self.fit_offset)):
            need = 0
        else:
            need = self.n_params + 1 if table is None and height is None else 2
        if n_reg < need:
            return not_identifiable(self.name, residuals,
                                    f"needs at least {need} objects with a metric "
                                    "prior registered to the observation")
        scale, offset = fit_bias(reg if n_reg else None, self.fit_scale, self.fit_offset, table,
                                 height)
        after = residuals
        if n_reg:
            after = replace(after, registration=corrected_registration(reg, scale, offset))
        if residuals.support is not None:
            after = replace(after, support=corrected_support(residuals.support, scale, offset))
        if residuals.table_shape is not None:
            after = replace(after, table_shape=corrected_table(residuals.table_shape, scale,
                                                               offset))
        params = {"scale": scale, "offset_m": offset}
        size, unit = (scale, "") if self.fit_scale else (offset, "m")
        note = self.describe(params)
        if table is not None:
            note += (f" (the table's shape alone: {table.offset_m * 1000:+.1f} +- "
                     f"{table.sigma_m * 1000:.1f} mm)")
        if height is not None:
            note += (f" (the table lies {height.distance_m * 1000:.1f} mm from the camera, "
                     f"the declared world puts it at {height.model_distance_m * 1000:.1f} mm)")
        return make_fit(self.name, residuals, after, params, self.n_params, size, unit,
                        note=note)

    def noise_bar(self, residuals: Residuals, n_params: int, draws: int, quantile: float,
                  seed: int) -> Optional[float]:
        """What noise alone explains: the prior scales bootstrapped over objects (centred),
        the table's offset drawn from its own noise (N(0, sigma_T)), the table's height
        from its own (N(0, sigma_h)); at least the sampling quantile of the combined
        estimate (:func:`mixed_sampling_bar`)."""
        table, _ = self.table_evidence(residuals)
        height = height_evidence(residuals.support)
        if table is None and height is None:
            return super().noise_bar(residuals, n_params, draws, quantile, seed)
        reg = residuals.registration
        enough = reg is not None and len(reg.used()) >= 3
        nulls = (list(null_registrations(reg, draws, seed)) if enough else [None] * draws)
        rng = np.random.default_rng(seed + 1)
        base = replace(residuals, table_shape=None) if table is not None else residuals
        values = []
        for null in nulls:
            drawn = None
            if table is not None:
                drawn = TableOffsetEvidence(float(rng.normal(0.0, table.sigma_m)),
                                            table.sigma_m, 0.0)
            trial = replace(base, registration=null)
            if height is not None:
                trial = replace(trial, support=with_height(
                    residuals.support, float(rng.normal(0.0, height.sigma_m))))
            fit = self.fit_with(trial, drawn)
            if fit.identifiable:
                values.append(fit.explained_sse
                              + (drawn.explained(fit.params["offset_m"]) if drawn else 0.0))
        boot = float(np.quantile(values, quantile)) if values else 0.0
        if n_params == 1:
            # the share of the information with a known noise level (the table's), against
            # the priors' with their noise level's dof, even where too few to bootstrap
            known = 0.0
            if table is not None:
                known += 1.0 / table.sigma_m ** 2
            if height is not None:
                known += height.information(self.fit_scale)
            if self.fit_scale:
                n_used = len(reg.used()) if reg is not None else 0
                priors = n_used / reg.scale_sigma ** 2 if n_used else 0.0
            else:
                priors = offset_information_from_priors(reg)
            share = known / (known + priors)
            bar = mixed_sampling_bar(reg.noise_dof if reg is not None else None, share,
                                     quantile, seed=seed)
        else:
            bar = (sampling_bar(reg, n_params, quantile) if enough
                   else float(chi2.ppf(quantile, n_params)))
        return max(boot, bar)

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
