"""Stage ``diagnose``: trace the residual to an effect the model lacks, and measure the fix.

1. Measure the residuals of the current reconstruction (registration, support, depth,
   physical rollout, observed push): :mod:`r2s.diagnose.measure.scene_dir`.
2. Fit every candidate effect of the catalogue and rank them by BIC against "no effect":
   :mod:`r2s.diagnose.stats.ranking`.
3. With an effect found, rerun the affected stages on a temporary copy of the scene with
   the effect in the model, and measure the residual and (with ``gt/``) the ground-truth
   errors again: :mod:`r2s.runner.rerun`.
4. Write ``diagnose/report.json``, ``report.md`` and ``residuals.png``. With
   ``apply=true`` the effect is kept in ``manifest.model["effects"]``: the stages that
   apply the model (init, texture, evaluate: input level; physopt, export: state level)
   then count as stale and ``r2s run`` reruns them with it; without it nothing outside
   ``diagnose/`` changes.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator

import numpy as np

from r2s.diagnose.effects import all_effects
from r2s.diagnose.stats.camera_or_table import camera_or_table
from r2s.diagnose.plots import colour_figure, edge_figure, residual_figure, structure_figure
from r2s.diagnose.stats.colour_test import Z_THRESHOLD as COLOUR_Z, ColourFinding
from r2s.diagnose.stats.texture_depth import Z_THRESHOLD as TEXTURE_Z
from r2s.diagnose.stats.edge_alignment import (MIN_SHIFT_PX as EDGE_SHIFT_PX,
                                               MIN_TURN_DEG as EDGE_TURN_DEG, EdgeFinding)
from r2s.diagnose.stats.ranking import NoiseBar
from r2s.diagnose.report import ReportInput, build_report, markdown
from r2s.diagnose.measure.scene_dir import MeasureSettings
from r2s.errors import R2SError
from r2s.io.atomic import atomic_write_bytes, atomic_write_json, atomic_write_text
from r2s.io.manifest import Manifest, load_manifest, save_manifest
from r2s.io.paths import DIAGNOSE_REPORT_FILE, ScenePaths
from r2s.runner.base import StageContext, StageOptions, StageSpec, model_hashes
from r2s.runner.diagnose_loop import LoopConfig, release, run_loop
from r2s.runner.registry import PIPELINE, get_stage
from r2s.runner.rerun import model_with_fits


class Options(StageOptions):
    apply: bool = Field(False, description="Keep the chosen effect in the scene's model "
                                           "(manifest.model); later stages and 'r2s run' use it.")
    effects: list[str] = Field(default_factory=list,
                               description="Effects to consider, comma-separated (default: all).")
    max_effects: int = Field(3, ge=1, le=4, description="How many effects the loop may keep.")
    max_steps: int = Field(4, ge=1, le=8, description="Loop steps (effects tried, kept or "
                                                     "reverted) at most.")
    budget_s: float = Field(3600.0, gt=0, description="Start no new loop step after this "
                                                      "many seconds.")
    lookahead: bool = Field(True, description="Rank the leading effects by the best two-step "
                                               "path (the effect, then the best second on "
                                               "what it leaves) instead of one at a time.")
    joint_refit: bool = Field(True, description="Refit interacting kept effects together at "
                                                "the end (one more rerun).")
    jump_tolerance_m: float = Field(
        0.02, ge=0, description="A step is reverted when its rerun moved an object's init "
                                "reconstruction this much more than its observed points "
                                "moved (a fit that flipped; r2s/diagnose/measure/"
                                "reconstruction_jumps.py), m; 0: off.")
    decisive_fall: float = Field(
        25.0, ge=0, description="A step whose claimed residual (normalised SSE) fell by at "
                                "least this is kept even when an object's fit flipped in "
                                "its rerun (the flip is named in its reason); 0: never.")
    camera_prior_odds: float = Field(
        4.0, gt=0, description="Prior odds of a camera extrinsic error against a tilted table "
                               "when the table is a few degrees off the declared vertical "
                               "(table_tilt carries 2 ln(odds) BIC units).")
    noise_draws: int = Field(200, ge=0, description="Bootstrap draws of noise alone over the "
                                                    "objects (0: no noise bar).")
    noise_quantile: float = Field(0.99, gt=0.5, lt=1.0,
                                  description="An effect must explain more than noise alone "
                                              "explains in this share of the draws.")
    structure_alpha: float = Field(1e-3, gt=0, lt=1, description="Level of the test for "
                                                                 "structure in the residual.")
    colour_z: float = Field(COLOUR_Z, gt=0, description="A depth error that depends on the "
                                                   "surface's grey level is reported when the "
                                                   "registered priors' residual gives |z| at "
                                                   "least this (diagnose/stats/colour_test.py; "
                                                   "clean scenes reach 4.8).")
    texture_z: float = Field(TEXTURE_Z, gt=0, description="A depth error that depends on the "
                             "surface's grey level is reported when the objects' depth, in its "
                             "detail within 8 px patches, follows their print's grey level "
                             "with |z| at least this (diagnose/stats/texture_depth.py; scenes "
                             "without one reach 3.8).")
    edge_shift_px: float = Field(EDGE_SHIFT_PX, gt=0, description="The depth image's edges "
                                 "lying this many pixels or more off the masks' edges (most "
                                 "objects agreeing) are reported as a depth-to-colour "
                                 "misregistration (diagnose/stats/edge_alignment.py; clean "
                                 "scenes reach 1.2).")
    edge_turn_deg: float = Field(EDGE_TURN_DEG, gt=0, description="The depth image's edges "
                                 "lying turned this many degrees or more against the masks' "
                                 "edges about the image centre, turning raising the count of "
                                 "outline pixels on a depth edge by 10 % or more, are reported "
                                 "as a depth-to-colour misregistration (clean scenes reach "
                                 "0.33 deg at such a gain).")
    table_shape_sigma_m: float = Field(0.0004, gt=0, description="Noise of a table tile's "
                                                                 "mean distance to its plane.")
    rerun: bool = Field(True, description="Rerun the affected stages on a copy of the scene to "
                                          "measure the residual and gt errors after.")
    rerun_stages: list[str] = Field(default_factory=list,
                                    description="Stages to rerun on the copy (default: those "
                                                "that ran, from the first one affected).")
    min_evidence: float = Field(2.0, ge=0, description="An effect needs delta BIC below minus "
                                                       "this to be chosen.")
    tie_tolerance: float = Field(2.0, ge=0, description="Effects within this delta BIC of the "
                                                        "best are reported as indistinguishable.")
    camera_rotation_penalty: float = Field(
        0.0, ge=0, description="Extra evidence (BIC units) camera_rotation needs on top of "
                               "the prior odds.")
    scale_sigma: float = Field(0.01, gt=0, description="Floor of the relative size error of one "
                                                       "prior (the priors' measured spread is "
                                                       "used when larger).")
    prior_scale_sigma: float = Field(0.025, gt=0, description="Prior spread of one prior's "
                                                               "size error (log), pooled with "
                                                               "the measured spread (measured "
                                                               "on clean scenes: "
                                                               "docs/diagnose.md section 4).")
    prior_scale_dof: float = Field(20.0, ge=0, description="How many objects' worth that "
                                                           "prior spread counts for.")
    support_sigma_deg: float = Field(0.3, gt=0, description="Noise of each table tilt component, "
                                                            "degrees.")
    table_height: Literal["auto", "on", "off"] = Field(
        "auto", description="Use the table's height at the declared world's origin as "
                            "evidence (auto: when the fitted table passes within 15 % of "
                            "the camera distance of it; docs/diagnose.md section 2).")
    table_height_sigma_m: float = Field(0.002, gt=0, description="Noise of the table's height "
                                                                 "at the world origin, m.")
    min_fitness: float = Field(0.6, ge=0, le=1, description="An object's shape fits the data when "
                                                            "this share of its points lies on it.")
    max_rmse_m: float = Field(0.004, gt=0, description="... and their RMS distance is below this.")
    min_prior_points: int = Field(150, ge=0, description="A prior's scale counts as evidence "
                                                         "of a depth bias only when its object "
                                                         "is seen by at least this many points "
                                                         "(fewer: its scale fit errs by ~20 %).")
    physics: bool = Field(True, description="Measure the physical residual (PyBullet rollout).")
    physics_source: Literal["auto", "init", "geomopt", "physopt"] = Field(
        "auto", description="State rolled out (auto: geomopt, else init).")
    com_from_rollout: bool = Field(
        False, description="Fit and apply a COM offset for an object that rocks in the "
                           "rollout of geomopt's state. Off: the shift is reported but not "
                           "applied, since after the whole pipeline such shifts were applied "
                           "to 2 of 12 held-out clean scenes even at 100:1 odds per object "
                           "(docs/diagnose.md section 10).")
    horizon_s: float = Field(1.0, gt=0, description="Rollout length, seconds.")
    sigma_translation_m: float = Field(0.015, gt=0, description="Noise of an object's rollout "
                                                               "displacement, metres.")
    sigma_rotation_deg: float = Field(5.0, gt=0, description="Noise of an object's rollout "
                                                             "rotation, degrees.")
    interaction_sigma_m: float = Field(0.005, gt=0, description="Noise of an observed push "
                                                                "displacement component, metres.")
    interaction_source: Literal["auto", "init", "geomopt", "physopt"] = Field(
        "auto", description="State the observed push is simulated on (auto: the rollout's "
                            "when the struck objects rest in it; else physopt's, at rest, "
                            "when it ran).")
    keep_copy: bool = Field(False, description="Keep the rerun copy (its path is in the report).")
    plots: bool = Field(True, description="Write residuals.png.")

    @field_validator("effects", "rerun_stages", mode="before")
    @classmethod
    def _split(cls, v: object) -> object:
        if isinstance(v, str):
            return [s.strip() for s in v.split(",") if s.strip()]
        return v


def inputs(paths: ScenePaths, options: Options, manifest: Manifest) -> list[Path]:  # noqa: ARG001
    return [paths.input, paths.stage_dir("init"), paths.stage_dir("geomopt"),
            paths.stage_dir("physopt"), paths.export, paths.metrics, paths.gt]


def model_not_in_effect(paths: ScenePaths, manifest: Manifest) -> list[str]:
    """Notes for stages whose result predates the scene's current model (an effect kept by
    ``apply=true`` without ``r2s run`` since): the residuals then mix two models."""
    stale = []
    for name in PIPELINE:
        rec = manifest.stages.get(name)
        if rec is None or rec.status != "done":
            continue
        spec = get_stage(name)
        now = model_hashes(spec, manifest)
        then = {k: v for k, v in rec.input_hashes.items() if k.startswith("manifest.model")}
        if now != then:
            stale.append(name)
    if not stale:
        return []
    return [f"the scene's model changed after {', '.join(stale)} ran; run 'r2s run "
            f"{paths.root}' first so that the residuals are measured with it"]


def settings_of(options: Options) -> MeasureSettings:
    return MeasureSettings(
        scale_sigma=options.scale_sigma, support_sigma_deg=options.support_sigma_deg,
        prior_scale_sigma=options.prior_scale_sigma, prior_scale_dof=options.prior_scale_dof,
        table_shape_sigma_m=options.table_shape_sigma_m,
        table_height=options.table_height, table_height_sigma_m=options.table_height_sigma_m,
        min_fitness=options.min_fitness, max_rmse_m=options.max_rmse_m,
        min_prior_points=options.min_prior_points,
        physics_source=options.physics_source, physics=options.physics,
        com_from_rollout=options.com_from_rollout,
        horizon_s=options.horizon_s, sigma_translation_m=options.sigma_translation_m,
        sigma_rotation_deg=options.sigma_rotation_deg,
        interaction_sigma_m=options.interaction_sigma_m,
        interaction_source=options.interaction_source)


def _catalogue(options: Options) -> dict:
    cat = all_effects()
    if not options.effects:
        return cat
    unknown = [e for e in options.effects if e not in cat]
    if unknown:
        raise R2SError(f"unknown effect(s) {', '.join(unknown)}; known: {', '.join(cat)}")
    return {k: v for k, v in cat.items() if k in options.effects}


def loop_config(options: Options) -> LoopConfig:
    return LoopConfig(
        max_steps=options.max_steps, max_effects=options.max_effects, budget_s=options.budget_s,
        min_evidence=options.min_evidence, tie_tolerance=options.tie_tolerance,
        penalties={"camera_rotation": options.camera_rotation_penalty,
                   "table_tilt": float(2.0 * np.log(options.camera_prior_odds))},
        noise=(NoiseBar(options.noise_draws, options.noise_quantile)
               if options.noise_draws > 0 else None),
        rerun=options.rerun, rerun_stages=options.rerun_stages or None,
        structure_alpha=options.structure_alpha, colour_z=options.colour_z,
        texture_z=options.texture_z,
        edge_shift_px=options.edge_shift_px, edge_turn_deg=options.edge_turn_deg,
        joint_refit=options.joint_refit, jump_tolerance_m=options.jump_tolerance_m,
        decisive_fall=options.decisive_fall,
        lookahead=options.lookahead)


def run(ctx: StageContext) -> dict:
    paths, options, progress = ctx.paths, ctx.options, ctx.progress
    effects = _catalogue(options)
    settings = settings_of(options)
    model = dict(ctx.manifest.model)

    loop = run_loop(paths.root, settings, loop_config(options), effects, model,
                    lambda m, f: progress(m, 0.95 * f))
    notes = list(loop.before.residuals.notes) + model_not_in_effect(paths, ctx.manifest)
    notes += loop.notes
    kept = list(loop.kept)
    measured_after = loop.final.residuals if kept and options.rerun else None
    copy = release(loop, options.keep_copy)
    if copy is not None:
        notes.append(f"rerun copy kept at {copy}")
    new_model = model_with_fits(model, kept) if options.apply else model
    predicted = kept[-1].residuals_after if kept else None
    report = build_report(ReportInput(
        scene=paths.root.name, rounds=tuple(loop.rounds), kept=tuple(kept),
        steps=tuple(st.summary() for st in loop.steps), before=loop.before.residuals,
        predicted=predicted, after=measured_after, physics_stage=loop.before.physics_stage,
        stages=tuple(loop.stages), gt_before=loop.gt_before, gt_after=loop.gt_final,
        applied=bool(options.apply and kept), model=new_model, notes=tuple(notes),
        structure_final=loop.structure_final.summary() if loop.structure_final else None,
        colour_final=loop.colour_final.summary() if loop.colour_final else None,
        texture_final=loop.texture_final.summary() if loop.texture_final else None,
        edge_final=loop.edge_final.summary() if loop.edge_final else None,
        unexplained=loop.unexplained.summary() if loop.unexplained else None,
        gravity=camera_or_table(loop.rounds[0] if loop.rounds else None, kept,
                                options.camera_prior_odds)))
    atomic_write_json(ctx.out_dir / DIAGNOSE_REPORT_FILE, report)
    atomic_write_text(ctx.out_dir / "report.md", markdown(report))
    if options.plots:
        title = (f"{paths.root.name}: " + (", ".join(report["decision"]) or "no effect"))
        atomic_write_bytes(ctx.out_dir / "residuals.png",
                           residual_figure(loop.before.residuals, predicted, measured_after,
                                           title))
        finding = loop.unexplained or loop.structure_final
        shape = loop.final.residuals.table_shape
        if isinstance(finding, EdgeFinding):
            atomic_write_bytes(ctx.out_dir / "structure.png", edge_figure(
                finding, f"{paths.root.name}: depth edges against mask edges, unexplained "
                         "structure"))
        elif isinstance(finding, ColourFinding):
            atomic_write_bytes(ctx.out_dir / "structure.png", colour_figure(
                finding, f"{paths.root.name}: residual left after the loop, unexplained "
                         "structure"))
        elif finding is not None and shape is not None:
            atomic_write_bytes(ctx.out_dir / "structure.png", structure_figure(
                finding, shape.width, shape.height,
                f"{paths.root.name}: residual left after the loop, "
                + ("unexplained structure" if loop.unexplained else "no structure found")))
    if options.apply and kept:
        manifest = load_manifest(paths.manifest)
        manifest.model = new_model
        save_manifest(paths.manifest, manifest)
    progress("done", 1.0)
    first = kept[0] if kept else None
    best = loop.rounds[0].best if loop.rounds else None
    return {"effect": ",".join(report["decision"]) or "none",
            "delta_bic": first.delta_bic if first else None,
            "score": first.score if first else None,
            "size": first.size if first else None,
            "steps": len(loop.steps),
            "unexplained": loop.unexplained.pattern if loop.unexplained else None,
            "residual_before": report["residual_total"]["before"],
            "residual_after": report["residual_total"]["after"],
            "runner_up": best.effect if best is not None else None,
            "applied": report["applied"]}


STAGE = StageSpec("diagnose", Options, inputs, run, uses_model=frozenset({"input", "state"}))
