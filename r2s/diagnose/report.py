"""``diagnose/report.json`` and ``diagnose/report.md``: what was found and what it changed.

report.json keys: ``decision`` (the effects kept, or ``[]`` for "no effect"),
``steps`` (one per loop step: the effect tried, the blocks it claimed, their SSE before,
predicted and measured after its rerun, the total residual and headline gt errors before
and after, kept or reverted and why), ``unexplained`` (a structured residual no kept
effect explains: its pattern; null when none), ``structure_test`` (the final test),
``gravity`` (camera or table: the choice, the alternative, the prior),
``chosen`` and ``ranking`` (every effect's fit per round: delta_BIC, explained SSE, k,
size, parameters), ``ties``, ``not_identifiable`` (effect -> why), ``residuals`` (per block
SSE: ``before``, ``predicted`` with the effect, ``after`` measured on the rerun copy),
``structure_before`` / ``structure_after``, ``gt_errors`` (``before`` / ``after``, null
without gt/), ``rerun`` (stages), ``applied`` and ``model`` (the scene's model after).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional

from r2s.diagnose.stats.blocks import blocks_of, total_n, total_sse
from r2s.diagnose.data import Residuals
from r2s.diagnose.effects import all_effects
from r2s.diagnose.stats.summary import sse_by_block, structure


@dataclass(frozen=True)
class ReportInput:
    """What the diagnose loop found, for :func:`build_report` (plain data).

    rounds : the ranking of every step (:class:`r2s.diagnose.stats.ranking.Round`); kept : the
    effects kept (fits); steps : one summary dict per step; before / predicted / after :
    residuals before, as the last kept fit predicts them, measured after the last kept
    rerun; structure_final / unexplained : summaries of the final structure test;
    colour_final : of the final colour test (r2s.diagnose.stats.colour_test); edge_final :
    of the depth-to-colour registration test (r2s.diagnose.stats.edge_alignment);
    texture_final : of the colour test on the depth's fine detail
    (r2s.diagnose.stats.texture_depth).
    """

    scene: str
    rounds: tuple
    kept: tuple
    steps: tuple
    before: Residuals
    predicted: Optional[Residuals]
    after: Optional[Residuals]
    physics_stage: Optional[str]
    stages: tuple
    gt_before: Optional[dict]
    gt_after: Optional[dict]
    applied: bool
    model: dict
    notes: tuple
    structure_final: Optional[dict] = None
    unexplained: Optional[dict] = None
    gravity: Optional[dict] = None
    colour_final: Optional[dict] = None
    edge_final: Optional[dict] = None
    texture_final: Optional[dict] = None


def build_report(r: ReportInput) -> dict[str, Any]:
    """The report.json content."""
    first = r.rounds[0] if r.rounds else None
    not_ident = {f.effect: f.note for f in (first.fits if first else ()) if not f.identifiable}
    before_total = total_sse(blocks_of(r.before))
    return {
        "format": "r2s-diagnose", "version": 2, "scene": r.scene,
        "decision": [c.effect for c in r.kept],
        "chosen": [c.summary() for c in r.kept],
        "steps": list(r.steps),
        "ranking": [[f.summary() for f in rnd.fits] for rnd in r.rounds],
        "ties": [list(rnd.ties) for rnd in r.rounds],
        "paths": [list(rnd.paths) for rnd in r.rounds],
        "not_identifiable": not_ident,
        "n_obs": total_n(blocks_of(r.before)),
        "physics_stage": r.physics_stage,
        "residuals": {"before": sse_by_block(r.before),
                      "predicted": sse_by_block(r.predicted) if r.kept else None,
                      "after": sse_by_block(r.after)},
        "residual_total": {"before": before_total,
                           "predicted": (total_sse(blocks_of(r.predicted))
                                         if r.kept and r.predicted is not None else None),
                           "after": (sum(sse_by_block(r.after).values())
                                     if r.after is not None else None)},
        "structure_before": structure(r.before),
        "structure_after": structure(r.after) if r.after is not None else None,
        "structure_test": r.structure_final,
        "colour_test": r.colour_final,
        "texture_test": r.texture_final,
        "edge_test": r.edge_final,
        "unexplained": r.unexplained,
        "gravity": r.gravity,
        "gt_errors": None if r.gt_before is None else {"before": r.gt_before,
                                                       "after": r.gt_after},
        "rerun": {"stages": list(r.stages)},
        "applied": r.applied, "model": r.model, "notes": list(r.notes),
    }


def _fmt(v: Any, digits: int = 3) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


GT_ROWS = ("state_centroid_error_mm", "state_centroid_error_median_mm", "state_support_normal_error_deg", "centroid_error_mm", "rotation_error_deg", "chamfer_mm", "stability_ratio",
           "com_error_mm", "com_error_max_mm", "support_normal_error_deg", "gravity_error_deg",
           "table_gravity_error_deg", "friction_error")


def _decision_lines(report: dict) -> list[str]:
    """What was found: the kept effects, an unexplained structure, camera or table, ties."""
    lines: list[str] = []
    if report["decision"]:
        for c in report["chosen"]:
            lines.append(f"**Effect found: `{c['effect']}`** ({c['note']}); "
                         f"delta BIC {c['delta_bic']:.1f} (score {c['score']:.1f}), explains "
                         f"{c['explained_sse']:.1f} of {c['sse_before']:.1f} (normalised SSE).")
    else:
        lines.append("**No effect**: no candidate explains more of the residual than its "
                     "parameters cost (BIC) and than noise alone explains.")
    un = report.get("unexplained")
    if un and un.get("test") == "surface colour":
        lines.append(f"\n**Unexplained structured residual**: {un['pattern']} "
                     f"(p = {un['p_value']:.2g}); no catalogued effect explains it "
                     "(see structure.png).")
    elif un and un.get("test") == "edge alignment":
        lines.append(f"\n**Unexplained structured residual**: {un['pattern']}; no catalogued "
                     "effect explains it (see structure.png).")
    elif un:
        lines.append(f"\n**Unexplained structured residual**: {un['pattern']} "
                     f"(chi-square {un['chi2']:.0f} on {un['dof']} tiles' degrees of freedom, "
                     f"p = {un['p_value']:.2g}); no catalogued effect explains it "
                     "(see structure.png).")
    grav = report.get("gravity")
    if grav:
        lines.append(f"\nCamera or table: **{grav['choice']}** (alternative: "
                     f"{grav['alternative']}; {grav['why']}).")
    for tie in report["ties"][:1]:
        if tie and report["decision"]:
            lines.append(f"\nIndistinguishable on this data (delta BIC within the tie "
                         f"tolerance): {', '.join(tie)}; the first is preferred.")
    return lines


def _step_lines(report: dict) -> list[str]:
    """The loop's steps as a table."""
    lines: list[str] = []
    if report.get("steps"):
        lines += ["", "## Steps", "",
                  "| step | effect | claimed blocks | claimed SSE before / predicted / after "
                  "| total SSE before -> after | gt centroid mm before -> after | kept |",
                  "| ---: | --- | --- | --- | --- | --- | --- |"]
        for st in report["steps"]:
            gb, ga = st.get("gt_before") or {}, st.get("gt_after") or {}
            lines.append(
                f"| {st['step'] + 1} | {st['kind']}: {', '.join(st['effects'])} | "
                f"{', '.join(st['claimed_blocks']) or '-'} | {_fmt(st['claimed_sse_before'])} / "
                f"{_fmt(st['claimed_sse_predicted'])} / {_fmt(st['claimed_sse_after'])} | "
                f"{_fmt(st['residual_total_before'])} -> {_fmt(st['residual_total_after'])} | "
                f"{_fmt(gb.get('state_centroid_error_mm'))} -> "
                f"{_fmt(ga.get('state_centroid_error_mm'))} | "
                f"{'yes' if st['kept'] else 'no'}: {st['reason']} |")
    return lines


def markdown(report: dict) -> str:
    """A short human-readable report."""
    effects = all_effects()
    lines = [f"# r2s diagnose: {report['scene']}", ""]
    lines += _decision_lines(report)
    lines += _step_lines(report)
    lines += ["", "## Ranking", "",
              "| effect | score | delta BIC | explained SSE | k | size | note |",
              "| --- | ---: | ---: | ---: | ---: | ---: | --- |"]
    for f in (report["ranking"][0] if report["ranking"] else []):
        if not f["identifiable"]:
            continue
        lines.append(f"| {f['effect']} | {f['score']:.1f} | {f['delta_bic']:.1f} | "
                     f"{f['explained_sse']:.1f} | {f['n_params']} | "
                     f"{_fmt(f['size'], 4)} {f['size_unit']} | {f['note']} |")
    if report["not_identifiable"]:
        lines += ["", "Not identifiable here:"]
        lines += [f"- `{k}`: {v}" for k, v in report["not_identifiable"].items()]
    lines += ["", "## Residual (normalised SSE per block)", "",
              "| block | before | predicted | after rerun |", "| --- | ---: | ---: | ---: |"]
    res = report["residuals"]
    for block in sorted(set(res["before"]) | set(res["after"] or {})):
        lines.append(f"| {block} | {_fmt(res['before'].get(block))} | "
                     f"{_fmt((res['predicted'] or {}).get(block))} | "
                     f"{_fmt((res['after'] or {}).get(block))} |")
    gt = report.get("gt_errors")
    if gt:
        lines += ["", "## Ground-truth errors", "", "| error | before | after |",
                  "| --- | ---: | ---: |"]
        for key in GT_ROWS:
            lines.append(f"| {key} | {_fmt(gt['before'].get(key))} | "
                         f"{_fmt((gt['after'] or {}).get(key))} |")
        if gt["before"].get("injected_effects"):
            lines.append(f"\nInjected (gt/): `{gt['before']['injected_effects']}`")
    sb = report["structure_before"]
    lines += ["", "## Residual structure (before)", ""]
    if "registration" in sb:
        r = sb["registration"]
        lines.append(f"- registration: mean prior scale {_fmt(r['mean_scale'], 4)}, spread "
                     f"{_fmt(r['scale_spread'], 3)} (log), over "
                     f"{sum(o['used'] for o in r['objects'])} objects")
    if "support" in sb:
        s = sb["support"]
        lines.append(f"- support: table normal tilted {s['tilt_deg']:.2f} deg from the model's "
                     f"up (noise {s['sigma_deg']:.2f} deg)")
    if "physics" in sb:
        p = sb["physics"]
        lines.append(f"- physics ({report['physics_stage']} state, {p['horizon_s']} s): moving "
                     f"objects {p['moving_ids']}, direction alignment "
                     f"{_fmt(p['direction_alignment'])}")
    if sb.get("depth") and sb["depth"].get("objects"):
        d = sb["depth"]["objects"]
        lines.append(f"- depth: objects {d['median_mm']:.2f} mm median, {d['rms_mm']:.2f} mm "
                     f"RMS (observed - model)")
    lines += ["", f"Applied to the scene's model: **{report['applied']}**"
              + ("" if report["applied"] else " (run with `--set apply=true` to keep it)")]
    if report["rerun"]["stages"]:
        lines.append(f"Stages rerun on a copy: {', '.join(report['rerun']['stages'])}")
    for note in report["notes"]:
        lines.append(f"- {note}")
    lines += ["", "## Catalogue", ""]
    lines += [f"- `{name}` (k={e.n_params}{' per object' if name in ('com_offset', 'friction') else ''},"
              f" {e.level}): {e.signature}" for name, e in effects.items()]
    return "\n".join(lines) + "\n"
