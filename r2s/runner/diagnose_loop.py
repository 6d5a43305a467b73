"""The diagnose loop: rank, apply the best effect, rerun, measure again, until nothing is left.

Orchestration only (it reruns stages, so it lives beside the stages, not in the diagnose
library); every decision is a library function:

1. measure the residuals (:func:`r2s.diagnose.measure.scene_dir.measure_scene`) and rank the effects
   not yet in the model (:func:`r2s.diagnose.stats.ranking.rank`); the first one that is
   supported (:func:`r2s.diagnose.stats.ranking.supported`: BIC, prior, noise bar) and does not
   leave a structured residual it only partly explains is the step's effect; where it is
   supported only as a second thing wrong beside such a structure, the fits of that kind
   compete without the table's shape (:func:`r2s.diagnose.stats.steps.choose_fit`);
2. rerun the affected stages on a fresh copy of the scene with every kept effect and this
   one in the copy's model (:func:`r2s.runner.rerun.rerun_with_effects`), measure the
   residuals and the ground-truth errors there;
3. keep the effect when the residual it claimed fell
   (:func:`r2s.diagnose.stats.steps.judge_step`), else revert it and leave it out;
4. stop when no effect is supported, after ``max_steps`` steps or ``budget_s`` seconds;
5. effects that interact (a depth bias with a camera rotation) are refitted together on
   the final residuals, rerun once more, and the refit kept when it lowers their claims;
6. what structure is left is tested (:func:`r2s.diagnose.stats.structure_test.test_structure`):
   a structured residual that no kept effect explains is reported as unexplained.
"""

from __future__ import annotations

import shutil
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Optional

from r2s.console import ProgressFn, silent_progress
from r2s.diagnose.data import Residuals
from r2s.diagnose.stats.blocks import blocks_of, total_sse
from r2s.diagnose.effects.base import Effect, EffectFit
from r2s.diagnose.stats.ranking import NoiseBar, Round, rank, supported
from r2s.runner.rerun import rerun_with_effects, temporary_root
from r2s.diagnose.measure.reconstruction_jumps import reconstruction_jumps
from r2s.diagnose.measure.scene_dir import Measured, MeasureSettings, measure_scene, scene_gt_errors
from r2s.diagnose.stats.steps import StepJudgement, choose_fit, claimed_blocks, judge_step
from r2s.diagnose.stats.colour_test import Z_THRESHOLD, ColourFinding, test_surface_colour
from r2s.diagnose.stats.texture_depth import Z_THRESHOLD as TEXTURE_Z, test_texture_depth
from r2s.diagnose.stats.edge_alignment import (MIN_SHIFT_PX, MIN_TURN_DEG, EdgeFinding,
                                               test_edge_alignment)
from r2s.diagnose.stats.structure_test import StructureFinding, test_structure


@dataclass(frozen=True)
class LoopConfig:
    """The stage's options that steer the loop."""

    max_steps: int = 4
    max_effects: int = 3
    budget_s: float = 3600.0
    min_evidence: float = 2.0
    tie_tolerance: float = 2.0
    penalties: dict = field(default_factory=dict)
    noise: Optional[NoiseBar] = NoiseBar()
    rerun: bool = True
    rerun_stages: Optional[list] = None
    structure_alpha: float = 1e-3
    colour_z: float = Z_THRESHOLD
    texture_z: float = TEXTURE_Z
    edge_shift_px: float = MIN_SHIFT_PX
    edge_turn_deg: float = MIN_TURN_DEG
    joint_refit: bool = True
    jump_tolerance_m: float = 0.02
    decisive_fall: float = 25.0
    lookahead: bool = True


@dataclass
class Step:
    """One step: the effect tried, the ranking it won, and what the rerun measured."""

    index: int
    kind: str  # "effect" or "joint refit"
    fits: list
    ranking: Optional[Round]
    judgement: StepJudgement
    stages: list
    residual_before: float
    residual_after: Optional[float]
    gt_before: Optional[dict]
    gt_after: Optional[dict]
    skipped: list = field(default_factory=list)

    def summary(self) -> dict:
        return {"step": self.index, "kind": self.kind,
                "effects": [f.effect for f in self.fits],
                "fits": [f.summary() for f in self.fits],
                "stages": self.stages, "residual_total_before": self.residual_before,
                "residual_total_after": self.residual_after,
                "gt_before": _headline(self.gt_before), "gt_after": _headline(self.gt_after),
                "skipped": self.skipped, **self.judgement.summary()}


@dataclass
class LoopResult:
    before: Measured
    final: Measured
    gt_before: Optional[dict]
    gt_final: Optional[dict]
    kept: list
    steps: list
    rounds: list
    stages: list
    unexplained: Optional[StructureFinding | ColourFinding | EdgeFinding]
    structure_final: Optional[StructureFinding]
    notes: list
    copy: Optional[Path] = None
    colour_final: Optional[ColourFinding] = None
    edge_final: Optional[EdgeFinding] = None
    texture_final: Optional[ColourFinding] = None


GT_HEADLINE = ("state_centroid_error_mm", "state_centroid_error_median_mm",
               "state_support_normal_error_deg", "centroid_error_mm", "chamfer_mm",
               "table_gravity_error_deg", "friction_error")


def _headline(gt: Optional[dict]) -> Optional[dict]:
    if gt is None:
        return None
    return {k: gt.get(k) for k in GT_HEADLINE if gt.get(k) is not None}


def _total(measured: Measured) -> float:
    return total_sse(blocks_of(measured.residuals))


def _choose(rnd: Round, residuals, cfg: LoopConfig) -> tuple[Optional[EffectFit], list]:
    """The step's effect of the round (:func:`r2s.diagnose.stats.steps.choose_fit`) and
    the fits passed over, with why."""
    return choose_fit(rnd.fits, residuals, lambda f: supported(f, cfg.min_evidence),
                      cfg.structure_alpha, cfg.min_evidence, cfg.tie_tolerance)


class _Copies:
    """Rerun copies under one temporary folder; only the current one is kept."""

    def __init__(self) -> None:
        self.work = temporary_root()
        self.current: Optional[Path] = None

    def rerun(self, root: Path, fits: list, cfg: LoopConfig, k: int,
              progress: ProgressFn) -> tuple[Path, list]:
        dest = Path(self.work.name) / f"step{k}"
        dest.mkdir()
        return rerun_with_effects(root, fits, dest, cfg.rerun_stages, progress)

    def keep(self, copy: Path) -> None:
        if self.current is not None and self.current != copy:
            shutil.rmtree(self.current.parent, ignore_errors=True)
        self.current = copy

    def drop(self, copy: Path) -> None:
        shutil.rmtree(copy.parent, ignore_errors=True)

    def detach(self) -> None:
        self.work._finalizer.detach()  # type: ignore[attr-defined]

    def cleanup(self) -> None:
        self.work.cleanup()


def _effect_step(root: Path, settings: MeasureSettings, cfg: LoopConfig, copies: _Copies,
                 k: int, fit: EffectFit, rnd: Round, skipped: list, kept: list,
                 current: Measured, gt_now: Optional[dict], progress: ProgressFn
                 ) -> tuple[Step, Optional[Measured], Optional[dict], Optional[Path]]:
    copy, stages = copies.rerun(root, kept + [fit], cfg, k, progress)
    after = measure_scene(copy, settings, None)
    gt_after = scene_gt_errors(copy)
    judgement = _unless_jumped(judge_step(fit, current.residuals, after.residuals),
                               copies.current or root, copy, stages, cfg)
    step = Step(k, "effect", [fit], rnd, judgement, stages, _total(current), _total(after),
                gt_now, gt_after, skipped)
    return step, after, gt_after, copy


def _unless_jumped(judgement: StepJudgement, before_root: Path, after_root: Path,
                   stages: list, cfg: LoopConfig) -> StepJudgement:
    """``judgement``, reverted when the rerun's init moved an object's reconstruction
    further than its observed points moved and away from its support
    (r2s.diagnose.measure.reconstruction_jumps): a fit that flipped off its support is not
    the effect's doing, and the residual the effect claims cannot tell the twin got worse.
    Unless the claimed residual fell by ``cfg.decisive_fall`` or more: then the effect is
    beyond doubt, the flip is the fit's instability (a 12 % depth scale, its claimed SSE
    99 -> 24, moved a 75-point box prior 31 mm further off the table), and the step is kept
    with the flipped object named in its reason."""
    if not judgement.kept or cfg.jump_tolerance_m <= 0 or "init" not in stages:
        return judgement
    before, after = Path(before_root) / "init", Path(after_root) / "init"
    if not (before / "state.json").is_file() or not (after / "state.json").is_file():
        return judgement
    jumps = [j for j in reconstruction_jumps(before, after, cfg.jump_tolerance_m)
             if j.lifts_off()]
    if not jumps:
        return judgement
    claimed_after = judgement.claimed_after
    fall = judgement.claimed_before - (judgement.claimed_before if claimed_after is None
                                       else claimed_after)
    if cfg.decisive_fall > 0 and fall >= cfg.decisive_fall:
        return replace(judgement, reason=f"{judgement.reason}; kept although "
                                         f"{jumps[0].describe()} in the rerun: a fall of "
                                         f"{fall:.1f} is decisive, and that object's fit is "
                                         "unstable (check it)")
    return replace(judgement, kept=False, flipped=True,
                   reason=f"reverted: {judgement.reason}, but {jumps[0].describe()} in the "
                          "rerun: a fit that flipped, not the effect")


def _joint_refit(root: Path, settings: MeasureSettings, cfg: LoopConfig, copies: _Copies,
                 k: int, effects: dict, kept: list, current: Measured,
                 gt_now: Optional[dict], progress: ProgressFn):
    """Refit every kept effect on the final residuals (the others in the model) and rerun
    once with the increments; None when the kept effects do not interact."""
    names = {f.effect for f in kept}
    if not any(effects[n].interacts_with & (names - {n}) for n in names if n in effects):
        return None
    increments = []
    for f in kept:
        inc = effects[f.effect].fit(current.residuals)
        if inc.identifiable and inc.explained_sse > 0.5:
            increments.append(inc)
    if not increments:
        return None
    copy, stages = copies.rerun(root, kept + increments, cfg, k, progress)
    after = measure_scene(copy, settings, None)
    gt_after = scene_gt_errors(copy)
    claims = tuple(sorted({b for f in increments for b in claimed_blocks(f, current.residuals)}))
    sb = sum(b.sse for n, b in blocks_of(current.residuals).items() if n in claims)
    sa = sum(b.sse for n, b in blocks_of(after.residuals).items() if n in claims)
    sp = sum(sum(b.sse for n, b in blocks_of(f.residuals_after).items() if n in claims)
             for f in increments[:1]) if increments[0].residuals_after is not None else sb
    kept_it = bool(claims) and sa < sb
    judgement = StepJudgement(claims, sb, sp, sa, kept_it,
                              (f"joint refit kept: {sb:.1f} -> {sa:.1f}" if kept_it else
                               f"joint refit reverted: {sb:.1f} -> {sa:.1f}"))
    judgement = _unless_jumped(judgement, copies.current or root, copy, stages, cfg)
    step = Step(k, "joint refit", increments, None, judgement, stages, _total(current),
                _total(after), gt_now, gt_after)
    return step, after, gt_after, copy, increments


@dataclass
class _FlipRetries:
    """An effect reverted because its rerun flipped an object's fit off its support
    (:func:`_unless_jumped`) is tried once more after a later step is kept: the flip can be
    the doing of an effect not yet in the model (a 75-point box prior flipped when a lens
    was corrected with a 4 % depth scale still in the depth; with the scale kept, the lens
    is the same fit without the flip)."""

    pending: set = field(default_factory=set)
    retried: set = field(default_factory=set)

    def after_reverted(self, effect: str, judgement: StepJudgement) -> None:
        if judgement.flipped and effect not in self.retried:
            self.pending.add(effect)

    def after_kept(self, effect: str, excluded: set, notes: list) -> None:
        for name in sorted(self.pending):
            notes.append(f"{name} is tried again with {effect} in the model: its first rerun "
                         "flipped an object's fit off its support")
        excluded -= self.pending
        self.retried |= self.pending
        self.pending.clear()


def run_loop(root: Path, settings: MeasureSettings, cfg: LoopConfig,
             effects: dict[str, Effect], model: dict,
             progress: ProgressFn = silent_progress) -> LoopResult:
    """Run the loop on the scene at ``root`` (never written: every rerun is on a copy)."""
    t0 = time.monotonic()
    before = measure_scene(root, settings, model, lambda m, f: progress(m, 0.2 * f))
    gt_before = scene_gt_errors(root)
    current, gt_now = before, gt_before
    kept: list[EffectFit] = []
    steps: list[Step] = []
    rounds: list[Round] = []
    excluded: set[str] = set()
    retries = _FlipRetries()
    notes: list[str] = []
    copies = _Copies()
    stages: list[str] = []
    try:
        for k in range(cfg.max_steps):
            if len(kept) >= cfg.max_effects:
                break
            if time.monotonic() - t0 > cfg.budget_s:
                notes.append(f"stopped after {k} steps: the time budget ({cfg.budget_s:.0f} s) "
                             "ran out")
                break
            frac = 0.2 + 0.7 * k / cfg.max_steps
            progress(f"step {k + 1}: ranking", frac)
            names = {f.effect for f in kept} | excluded
            rnd = rank(current.residuals, {n: e for n, e in effects.items() if n not in names},
                       cfg.tie_tolerance, cfg.penalties, cfg.noise,
                       min_evidence=cfg.min_evidence, lookahead=cfg.lookahead)
            rounds.append(rnd)
            fit, skipped = _choose(rnd, current.residuals, cfg)
            if fit is None:
                if skipped:
                    notes.extend(s["why"] for s in skipped)
                break
            if not cfg.rerun:
                judgement = judge_step(fit, current.residuals, None)
                steps.append(Step(k, "effect", [fit], rnd, judgement, [], _total(current),
                                  None, gt_now, None, skipped))
                kept.append(fit)
                current = Measured(fit.residuals_after, current.physics_stage)
                continue
            progress(f"step {k + 1}: rerunning with {fit.effect}", frac + 0.1 / cfg.max_steps)
            step, after, gt_after, copy = _effect_step(root, settings, cfg, copies, k, fit, rnd,
                                                       skipped, kept, current, gt_now, progress)
            steps.append(step)
            if step.judgement.kept:
                kept.append(fit)
                current, gt_now, stages = after, gt_after, step.stages
                copies.keep(copy)
                retries.after_kept(fit.effect, excluded, notes)
            else:
                excluded.add(fit.effect)
                retries.after_reverted(fit.effect, step.judgement)
                copies.drop(copy)
        if cfg.rerun and cfg.joint_refit and len(kept) >= 2:
            progress("joint refit of interacting effects", 0.92)
            out = _joint_refit(root, settings, cfg, copies, len(steps), effects, kept, current,
                               gt_now, progress)
            if out is not None:
                step, after, gt_after, copy, increments = out
                steps.append(step)
                if step.judgement.kept:
                    kept.extend(increments)
                    current, gt_now, stages = after, gt_after, step.stages
                    copies.keep(copy)
                else:
                    copies.drop(copy)
        unexplained, final_structure, colour, texture, edges = _final_tests(
            current.residuals, cfg)
        result = LoopResult(before, current, gt_before, gt_now if kept else None, kept, steps,
                            rounds, stages if kept else [], unexplained, final_structure, notes,
                            copies.current, colour_final=colour, edge_final=edges,
                            texture_final=texture)
    except BaseException:
        copies.cleanup()
        raise
    result._copies = copies  # type: ignore[attr-defined]
    return result


def _final_tests(res: Residuals, cfg: LoopConfig) -> tuple:
    """(unexplained, structure, colour, texture, edges) after the loop: the table's
    structure test; when the table is flat, is the objects' depth error colour's (against
    the registered priors, then in the depth's fine detail against the print's); and else,
    do the depth image and the masks not line up? ``unexplained`` is the first structured
    finding."""
    structure = test_structure(res, cfg.structure_alpha)
    colour = test_surface_colour(res, cfg.colour_z)
    dm = res.depth_map
    texture = (test_texture_depth(dm.depth_m, dm.grey, dm.masks, cfg.texture_z)
               if dm is not None and dm.masks is not None else None)
    edges = _edge_test(res, cfg.edge_shift_px, cfg.edge_turn_deg)
    found = [f for f in (structure, colour, texture, edges) if f is not None and f.structured]
    return (found[0] if found else None), structure, colour, texture, edges


def _edge_test(res: Residuals, min_shift_px: float, min_turn_deg: float
               ) -> Optional[EdgeFinding]:
    """Depth-to-colour registration test (r2s.diagnose.stats.edge_alignment) on the
    observation as the current model corrects it; None without a depth map or masks."""
    dm = res.depth_map
    if dm is None or dm.masks is None:
        return None
    return test_edge_alignment(dm.depth_m, dm.masks, min_shift_px=min_shift_px,
                               min_turn_deg=min_turn_deg)


def release(result: LoopResult, keep_copy: bool) -> Optional[Any]:
    """Delete the rerun copies (or keep the current one: its path is returned)."""
    copies: _Copies = result._copies  # type: ignore[attr-defined]
    if keep_copy and copies.current is not None:
        copies.detach()
        return copies.current
    copies.cleanup()
    return None
