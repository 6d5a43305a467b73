#!/usr/bin/env python
"""Prior or completion, from what init already wrote: a margin rule against gt, no rerun.

For every object with a prior in each scene's ``init/state.json`` whose ``prior_choice``
record holds both candidates' view scores, reads the two candidate meshes init saved (the
kept one in ``init/meshes``; a replaced prior in ``init/replaced_priors``, a kept prior's
completion in ``init/alternates``), measures each one's Chamfer distance (mm) against the
gt object of the same id, and applies :func:`r2s.geometry.prior_choice.choose` with the
margins given (no rest rule: a completion chosen for rest is kept as recorded). Prints the
objects whose choice differs from the recorded one, then per scene group (the folder above
the scene) the objects, how many changed, in how many the new choice is closer to gt, and
the mean CD of the recorded and the new choices.

Usage:
  python scripts/prior_choice_recorded.py bench/*/* [--large-iou-gain 1.0] [--ucd-gain-mm U]

gt/ is read here only; init never reads it. Scenes without init or gt are skipped.
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from dataclasses import fields
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.geometry.prior_choice import ChoiceMargins, ViewScore, choose  # noqa: E402
from r2s.io.mesh_io import load_mesh  # noqa: E402
from r2s.io.paths import INIT_ALTERNATES_DIR, INIT_REPLACED_PRIORS_DIR  # noqa: E402
from r2s.io.scene_json import read_gt_scene  # noqa: E402
from r2s.io.state import read_state  # noqa: E402
from r2s.metrics.geometry import chamfer_distance_mm  # noqa: E402


def _posed(folder: Path, obj_id: int):
    """The world-frame mesh of ``obj_id`` in the state of ``folder`` (None if absent)."""
    if not (folder / "state.json").is_file():
        return None
    state = read_state(folder)
    if obj_id not in {o.id for o in state.objects}:
        return None
    o = state.object(obj_id)
    return load_mesh(folder / o.mesh).apply_transform(o.pose)


def scene_rows(scene: Path, margins: ChoiceMargins) -> list[dict]:
    """Per object with both candidates: recorded and new choice, CD (mm) of each candidate."""
    init = scene / "init"
    gt = {o.id: o for o in read_gt_scene(scene / "gt" / "scene.json").objects}
    rows = []
    for o in read_state(init).objects:
        record = (o.model_extra or {}).get("prior_choice") or {}
        if not record.get("prior") or not record.get("completion") or o.id not in gt:
            continue
        kept = record["chosen"]
        prior = _posed(init if kept == "prior" else init / INIT_REPLACED_PRIORS_DIR, o.id)
        completion = _posed(init / INIT_ALTERNATES_DIR if kept == "prior" else init, o.id)
        if prior is None or completion is None:
            continue
        g = gt[o.id]
        gt_mesh = load_mesh(scene / "gt" / g.mesh).apply_transform(np.asarray(g.world_from_object))
        scores = [ViewScore(**record[k]) for k in ("prior", "completion")]
        new = kept if kept == "completion" else choose(*scores, margins)[0]
        rows.append({"scene": scene, "id": o.id, "recorded": kept, "new": new,
                     "scores": scores, "cd_prior": chamfer_distance_mm(prior, gt_mesh),
                     "cd_completion": chamfer_distance_mm(completion, gt_mesh)})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="+", type=Path)
    for f in fields(ChoiceMargins):  # --iou-gain, --ucd-gain-mm, ... with their defaults
        ap.add_argument("--" + f.name.replace("_", "-"), type=float, default=f.default)
    args = ap.parse_args()
    margins = ChoiceMargins(**{f.name: getattr(args, f.name) for f in fields(ChoiceMargins)})
    groups: dict[str, list[dict]] = defaultdict(list)
    print("| scene | id | prior IoU / UCD mm / free | completion IoU / UCD mm / free "
          "| CD prior / completion mm | recorded -> new |")
    print("|---|---:|---|---|---|---|")
    for scene in args.scenes:
        if not (scene / "init" / "state.json").is_file() or not (scene / "gt" / "scene.json").is_file():
            continue
        for r in scene_rows(scene, margins):
            groups[scene.parent.name].append(r)
            if r["new"] != r["recorded"]:
                p, c = r["scores"]
                print(f"| {scene.parent.name}/{scene.name} | {r['id']} "
                      f"| {p.iou:.3f} / {p.ucd_mm:.2f} / {p.free_space:.3f} "
                      f"| {c.iou:.3f} / {c.ucd_mm:.2f} / {c.free_space:.3f} "
                      f"| {r['cd_prior']:.1f} / {r['cd_completion']:.1f} "
                      f"| {r['recorded']} -> {r['new']} |")
    print("\n| group | objects | changed | closer to gt after the change | mean CD recorded -> new [mm] |")
    print("|---|---:|---:|---:|---|")
    for name, rows in sorted(groups.items()):
        cd = {k: [r["cd_prior"] if r[k] == "prior" else r["cd_completion"] for r in rows]
              for k in ("recorded", "new")}
        changed = sum(r["new"] != r["recorded"] for r in rows)
        closer = sum(n < o for n, o in zip(cd["new"], cd["recorded"]))
        print(f"| {name} | {len(rows)} | {changed} | {closer} | "
              f"{np.mean(cd['recorded']):.2f} -> {np.mean(cd['new']):.2f} |")


if __name__ == "__main__":
    main()
