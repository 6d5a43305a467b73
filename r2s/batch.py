"""Aggregate ``evaluate/metrics.json`` of many scenes into one table (terminal + markdown),
and ``r2s batch``'s report (one row per scene, then the aggregate; markdown and CSV).

Stability is pooled over instances (stable instances / all instances, as in the paper's
Table I); the other columns are means over scenes. Time per scene is the sum of the
recorded stage times in each scene's manifest, evaluation excluded.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from r2s.console import print_table
from r2s.errors import R2SError
from r2s.io.atomic import atomic_write_text
from r2s.io.manifest import load_manifest
from r2s.io.paths import ScenePaths

COLUMNS: tuple[tuple[str, str, str], ...] = (
    # (header, key in the aggregate, format)
    ("Stab. [%]", "stability_pct", "{:.1f}"),
    ("Set. [s]", "settling_time_s", "{:.2f}"),
    ("V_t [m/s]", "mean_linear_speed_mps", "{:.3f}"),
    ("Ω_t [rad/s]", "mean_angular_speed_radps", "{:.3f}"),
    ("CD [mm]", "chamfer_mm", "{:.1f}"),
    ("FS", "fscore", "{:.2f}"),
    ("IoU", "iou", "{:.2f}"),
    ("PSNR", "psnr", "{:.2f}"),
    ("SSIM", "ssim", "{:.3f}"),
    ("Pen. [mm]", "max_penetration_mm", "{:.1f}"),
    ("Float.", "floating_objects", "{:.1f}"),
    ("Time [s]", "time_per_scene_s", "{:.1f}"),
)


@dataclass
class Aggregate:
    scenes: int
    values: dict[str, float]


def _mean(values: list) -> float:
    vals = [float(v) for v in values if v is not None]
    return float(np.mean(vals)) if vals else float("nan")


def aggregate(scene_dirs: Sequence[Path], stages_timed: Optional[Sequence[str]] = None) -> Aggregate:
    """Pool the metrics of ``scene_dirs`` (each must have ``evaluate/metrics.json``)."""
    rows, stable, instances, times = [], 0, 0, []
    for d in scene_dirs:
        paths = ScenePaths(Path(d))
        if not paths.metrics.is_file():
            raise R2SError(f"{paths.metrics}: missing; run 'r2s evaluate {d}' first")
        m = json.loads(paths.metrics.read_text())
        rows.append(m)
        objs = m.get("objects", [])
        stable += sum(1 for o in objs if o.get("stable"))
        instances += len(objs)
        manifest = load_manifest(paths.manifest)
        names = stages_timed or [n for n in manifest.stages if n not in ("evaluate", "diagnose")]
        times.append(sum(manifest.stages[n].seconds or 0.0 for n in names if n in manifest.stages))
    values = {key: _mean([r.get(key) for r in rows]) for _, key, _ in COLUMNS}
    values["stability_pct"] = 100.0 * stable / instances if instances else float("nan")
    values["time_per_scene_s"] = _mean(times)
    return Aggregate(scenes=len(rows), values=values)


def markdown_row(label: str, agg: Aggregate) -> str:
    cells = [fmt.format(agg.values[key]) if np.isfinite(agg.values[key]) else "n/a"
             for _, key, fmt in COLUMNS]
    return f"| {label} | {agg.scenes} | " + " | ".join(cells) + " |"


def markdown_header() -> str:
    heads = ["Method", "Scenes"] + [h for h, _, _ in COLUMNS]
    return "| " + " | ".join(heads) + " |\n|" + "---|" * len(heads)


def aggregate_metrics(scene_dirs: Sequence[Path], out: Optional[Path] = None,
                      label: str = "r2s") -> Aggregate:
    """CLI helper: print the pooled table and optionally write it as markdown."""
    agg = aggregate(scene_dirs)
    rows = [[h, fmt.format(agg.values[k]) if np.isfinite(agg.values[k]) else "n/a"]
            for h, k, fmt in COLUMNS]
    print_table(f"{label}: {agg.scenes} scenes", ["metric", "value"], rows)
    if out is not None:
        atomic_write_text(Path(out), markdown_header() + "\n" + markdown_row(label, agg) + "\n")
    return agg


def _cells(agg: Aggregate) -> list[str]:
    return [fmt.format(agg.values[key]) if np.isfinite(agg.values[key]) else "n/a"
            for _, key, fmt in COLUMNS]


def write_batch_report(root: Path, runs: Sequence[tuple[Path, bool, float]], out_dir: Path,
                       label: str = "r2s") -> tuple[Path, Path]:
    """``report.md`` and ``report.csv`` in ``out_dir``: one row per scene of ``runs``
    (``(scene, ok, wall seconds)``; scenes named relative to ``root``), then the aggregate
    of the scenes that have metrics (as ``r2s report``). Returns both paths."""
    import csv
    import io

    heads = [h for h, _, _ in COLUMNS]
    md_lines = ["| Scene | Status | Wall [s] | " + " | ".join(heads) + " |",
                "|" + "---|" * (len(heads) + 3)]
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["scene", "status", "wall_s"] + [key for _, key, _ in COLUMNS])
    with_metrics: list[Path] = []
    for scene, ok, seconds in runs:
        name = str(Path(scene).relative_to(root)) if Path(scene) != Path(root) else "."
        has = ScenePaths(Path(scene)).metrics.is_file()
        status = "ok" if ok else "failed"
        if has and ok:
            with_metrics.append(Path(scene))
            agg = aggregate([scene])
            cells, raw = _cells(agg), [agg.values[k] for _, k, _ in COLUMNS]
        else:
            cells, raw = ["n/a"] * len(COLUMNS), [""] * len(COLUMNS)
        md_lines.append(f"| {name} | {status} | {seconds:.1f} | " + " | ".join(cells) + " |")
        writer.writerow([name, status, f"{seconds:.3f}"] + [
            "" if v == "" or not np.isfinite(v) else f"{v:.6g}" for v in raw])
    if with_metrics:
        agg = aggregate(with_metrics)
        total = sum(s for _, _, s in runs)
        md_lines.append(f"| **{label}: {agg.scenes} scenes** | | {total:.1f} | "
                        + " | ".join(_cells(agg)) + " |")
        writer.writerow([f"{label} (all)", f"{agg.scenes} scenes", f"{total:.3f}"] + [
            f"{agg.values[k]:.6g}" if np.isfinite(agg.values[k]) else ""
            for _, k, _ in COLUMNS])
    out_dir = Path(out_dir)
    md, csv_path = out_dir / "report.md", out_dir / "report.csv"
    atomic_write_text(md, "\n".join(md_lines) + "\n")
    atomic_write_text(csv_path, buf.getvalue())
    return md, csv_path
