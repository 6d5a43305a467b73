"""``diagnose/report.json`` and ``diagnose/report.md``: what was found and what it changed.

report.json keys: ``decision`` (the chosen effects, or ``[]`` for "no effect"),
``chosen`` and ``ranking`` (every effect's fit per round: delta_BIC, explained SSE, k,
size, parameters), ``ties``, ``not_identifiable`` (effect -> why), ``residuals`` (per block
SSE: ``before``, ``predicted`` with the effect, ``after`` measured on the rerun copy),
``structure_before`` / ``structure_after``, ``gt_errors`` (``before`` / ``after``, null
without gt/), ``rerun`` (stages), ``applied`` and ``model`` (the scene's model after).
"""

from __future__ import annotations

from typing import Any, Optional

from r2s.diagnose.effects import all_effects
from r2s.diagnose.ranking import Diagnosis
from r2s.diagnose.structure import sse_by_block, structure


def build_report(scene: str, diag: Diagnosis, physics_stage: Optional[str],
                 measured_after, rerun_stages: list[str], gt_before: Optional[dict],
                 gt_after: Optional[dict], applied: bool, model: dict,
                 notes: list[str]) -> dict[str, Any]:
    """The report.json content (``measured_after``: residuals of the rerun copy or None)."""
    last = diag.rounds[0] if diag.rounds else None
    not_ident = {f.effect: f.note for f in (last.fits if last else ()) if not f.identifiable}
    return {
        "format": "r2s-diagnose", "version": 1, "scene": scene,
        "decision": [c.effect for c in diag.chosen],
        "chosen": [c.summary() for c in diag.chosen],
        "ranking": [[f.summary() for f in r.fits] for r in diag.rounds],
        "ties": [list(r.ties) for r in diag.rounds],
        "not_identifiable": not_ident,
        "n_obs": diag.n_obs,
        "physics_stage": physics_stage,
        "residuals": {"before": sse_by_block(diag.residuals_before),
                      "predicted": sse_by_block(diag.residuals_after) if diag.chosen else None,
                      "after": sse_by_block(measured_after)},
        "residual_total": {"before": diag.sse_before,
                           "predicted": diag.sse_after if diag.chosen else None,
                           "after": (sum(sse_by_block(measured_after).values())
                                     if measured_after is not None else None)},
        "structure_before": structure(diag.residuals_before),
        "structure_after": structure(measured_after) if measured_after is not None else None,
        "gt_errors": None if gt_before is None else {"before": gt_before, "after": gt_after},
        "rerun": {"stages": rerun_stages},
        "applied": applied, "model": model, "notes": notes,
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


def markdown(report: dict) -> str:
    """A short human-readable report."""
    effects = all_effects()
    lines = [f"# r2s diagnose: {report['scene']}", ""]
    if report["decision"]:
        for c in report["chosen"]:
            lines.append(f"**Effect found: `{c['effect']}`** ({c['note']}); "
                         f"delta BIC {c['delta_bic']:.1f} (score {c['score']:.1f}), explains "
                         f"{c['explained_sse']:.1f} of {c['sse_before']:.1f} (normalised SSE).")
    else:
        lines.append("**No effect**: no candidate explains more of the residual than its "
                     "parameters cost (BIC).")
    for tie in report["ties"]:
        if tie and report["decision"]:
            lines.append(f"\nIndistinguishable on this data (delta BIC within the tie "
                         f"tolerance): {', '.join(tie)}; the first is preferred.")
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
