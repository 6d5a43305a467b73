"""Stage ``diagnose``: trace the residual to an effect the model lacks, and measure the fix.

1. Measure the residuals of the current reconstruction (registration, support, depth,
   physical rollout, observed push): :mod:`r2s.diagnose.scene`.
2. Fit every candidate effect of the catalogue and rank them by BIC against "no effect":
   :mod:`r2s.diagnose.ranking`.
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

from r2s.diagnose.effects import all_effects
from r2s.diagnose.plots import residual_figure
from r2s.diagnose.ranking import diagnose
from r2s.diagnose.report import build_report, markdown
from r2s.runner.rerun import model_with_fits, rerun_with_effects, temporary_root
from r2s.diagnose.scene import MeasureSettings, measure_scene, scene_gt_errors
from r2s.errors import R2SError
from r2s.io.atomic import atomic_write_bytes, atomic_write_json, atomic_write_text
from r2s.io.paths import DIAGNOSE_REPORT_FILE, ScenePaths
from r2s.runner.base import StageContext, StageOptions, StageSpec, model_hashes
from r2s.io.manifest import Manifest, load_manifest, save_manifest
from r2s.runner.registry import PIPELINE, get_stage


class Options(StageOptions):
    apply: bool = Field(False, description="Keep the chosen effect in the scene's model "
                                           "(manifest.model); later stages and 'r2s run' use it.")
    effects: list[str] = Field(default_factory=list,
                               description="Effects to consider, comma-separated (default: all).")
    max_effects: int = Field(1, ge=1, le=2, description="How many effects to put in the model.")
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
        20.0, ge=0, description="Extra evidence (BIC units) camera_rotation needs: a wrong "
                                "camera correction moves every object, a wrong table_tilt "
                                "none.")
    scale_sigma: float = Field(0.01, gt=0, description="Floor of the relative size error of one "
                                                       "prior (the priors' measured spread is "
                                                       "used when larger).")
    support_sigma_deg: float = Field(0.3, gt=0, description="Noise of each table tilt component, "
                                                            "degrees.")
    min_fitness: float = Field(0.6, ge=0, le=1, description="An object's shape fits the data when "
                                                            "this share of its points lies on it.")
    max_rmse_m: float = Field(0.004, gt=0, description="... and their RMS distance is below this.")
    physics: bool = Field(True, description="Measure the physical residual (PyBullet rollout).")
    physics_source: Literal["auto", "init", "geomopt", "physopt"] = Field(
        "auto", description="State rolled out (auto: geomopt, else init).")
    horizon_s: float = Field(1.0, gt=0, description="Rollout length, seconds.")
    sigma_translation_m: float = Field(0.015, gt=0, description="Noise of an object's rollout "
                                                               "displacement, metres.")
    sigma_rotation_deg: float = Field(5.0, gt=0, description="Noise of an object's rollout "
                                                             "rotation, degrees.")
    interaction_sigma_m: float = Field(0.005, gt=0, description="Noise of an observed push "
                                                                "displacement component, metres.")
    interaction_source: Literal["auto", "init", "geomopt", "physopt"] = Field(
        "auto", description="State the observed push is simulated on (auto: physopt, at rest, "
                            "when it ran; else the rollout's).")
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
        min_fitness=options.min_fitness, max_rmse_m=options.max_rmse_m,
        physics_source=options.physics_source, physics=options.physics,
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


def run(ctx: StageContext) -> dict:
    paths, options, progress = ctx.paths, ctx.options, ctx.progress
    effects = _catalogue(options)
    settings = settings_of(options)
    model = dict(ctx.manifest.model)

    before = measure_scene(paths.root, settings, model, lambda m, f: progress(m, 0.3 * f))
    diag = diagnose(before.residuals, effects, options.max_effects, options.min_evidence,
                    options.tie_tolerance, lambda m, f: progress(m, 0.3 + 0.2 * f),
                    penalties={"camera_rotation": options.camera_rotation_penalty})
    notes = list(before.residuals.notes) + model_not_in_effect(paths, ctx.manifest)
    gt_before = scene_gt_errors(paths.root)
    gt_after = measured_after = None
    stages: list[str] = []
    if diag.chosen and options.rerun:
        work = temporary_root()
        try:
            copy, stages = rerun_with_effects(paths.root, list(diag.chosen), Path(work.name),
                                              options.rerun_stages or None,
                                              lambda m, f: progress(m, 0.5 + 0.35 * f))
            progress("measuring the residual after", 0.86)
            after = measure_scene(copy, settings, None)
            measured_after = after.residuals
            gt_after = scene_gt_errors(copy)
            if options.keep_copy:
                work._finalizer.detach()  # type: ignore[attr-defined]
                notes.append(f"rerun copy kept at {copy}")
        finally:
            if not options.keep_copy:
                work.cleanup()

    new_model = model_with_fits(model, list(diag.chosen)) if options.apply else model
    report = build_report(paths.root.name, diag, before.physics_stage, measured_after, stages,
                          gt_before, gt_after, bool(options.apply and diag.chosen), new_model,
                          notes)
    atomic_write_json(ctx.out_dir / DIAGNOSE_REPORT_FILE, report)
    atomic_write_text(ctx.out_dir / "report.md", markdown(report))
    if options.plots:
        title = (f"{paths.root.name}: " + (", ".join(report["decision"]) or "no effect"))
        atomic_write_bytes(ctx.out_dir / "residuals.png",
                           residual_figure(diag.residuals_before,
                                           diag.residuals_after if diag.chosen else None,
                                           measured_after, title))
    if options.apply and diag.chosen:
        manifest = load_manifest(paths.manifest)
        manifest.model = new_model
        save_manifest(paths.manifest, manifest)
    progress("done", 1.0)
    best = diag.rounds[0].best if diag.rounds else None
    summary = {"effect": ",".join(report["decision"]) or "none",
               "delta_bic": diag.chosen[0].delta_bic if diag.chosen else None,
               "score": diag.chosen[0].score if diag.chosen else None,
               "size": diag.chosen[0].size if diag.chosen else None,
               "residual_before": diag.sse_before,
               "residual_after": report["residual_total"]["after"],
               "runner_up": best.effect if best is not None else None,
               "applied": report["applied"]}
    return summary


STAGE = StageSpec("diagnose", Options, inputs, run, uses_model=frozenset({"input", "state"}))
