#!/usr/bin/env python
"""Prior or completion, per object: the view scores init records and the CD against gt.

For each scene (a copy: init/ is rewritten), runs ``r2s init SCENE --set
prior_choice=prior`` and ``--set prior_choice=completion`` through the command line and
prints, per object with a prior, the scores init recorded for both candidates (silhouette
IoU with the others z-buffered, UCD mm, free-space violation; r2s/geometry/prior_choice.py),
the Chamfer distance (mm) of each candidate's init mesh against the gt object of the same
id, how far each went when set down alone on the table and how far its centre of mass went
down (objects standing alone on it; the rest rule), each candidate's lowest point above the
support plane (negative: into the table), and what ``prior_choice=auto`` would choose with
the default margins (or those given) and the default rest rule.
gt/ is read here only, to calibrate the margins; init never reads it. The copy's manifest
is left recording ``prior_choice=completion``, which a later ``r2s run`` reuses: run it with
``--set init.prior_choice=auto`` to go back to the default.

Usage:
  python scripts/prior_choice_table.py SCENE [SCENE ...] [--iou-gain G] [--ucd-gain-mm U]
      [--free-space-slack F] [--set INIT_KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.geometry.prior_choice import ChoiceMargins, Rest, ViewScore, choose  # noqa: E402
from r2s.geometry.plane import signed_distance  # noqa: E402
from r2s.io.mesh_io import load_mesh  # noqa: E402
from r2s.io.paths import ScenePaths  # noqa: E402
from r2s.io.scene_json import read_gt_scene  # noqa: E402
from r2s.io.state import read_state  # noqa: E402
from r2s.metrics.geometry import chamfer_distance_mm, posed  # noqa: E402


def _init(root: Path, mode: str, extra: list[str] = ()) -> dict[int, tuple[float, dict, float]]:
    """Run init with ``prior_choice=mode``; id -> (CD mm against gt, recorded scores, the
    mesh's lowest point above the support plane, mm: negative is below the table)."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    sets = [a for kv in extra for a in ("--set", kv)]
    subprocess.run([sys.executable, "-m", "r2s.cli", "init", str(root), "--set",
                    f"prior_choice={mode}", *sets], check=True, env=env, capture_output=True)
    paths = ScenePaths(root)
    gt = {g.id: g for g in read_gt_scene(paths.gt_scene).objects}
    out = {}
    state = read_state(paths.stage_dir("init"))
    for o in state.objects:
        record = getattr(o, "prior_choice", None)
        if record is None or o.id not in gt:
            continue
        mesh = posed(load_mesh(paths.stage_dir("init") / o.mesh), np.asarray(o.pose))
        truth = posed(load_mesh(paths.gt / gt[o.id].mesh),
                      np.asarray(gt[o.id].world_from_object))
        lowest_mm = 1000.0 * float(np.min(signed_distance(mesh.vertices, state.support.point,
                                                          state.support.normal)))
        out[o.id] = (chamfer_distance_mm(mesh, truth, seed=0), record, lowest_mm)
    return out


def _summary(rows: np.ndarray) -> str:
    """One line over the (K, 3) rows (CD prior, CD completion, replaced 0/1) of the priors
    with both candidates: how many the margins replace, how many of those are closer to
    gt as completions, and the mean CD at init of the choice, of all priors, of the better
    candidate of each."""
    replaced = rows[:, 2] > 0
    chosen = np.where(replaced, rows[:, 1], rows[:, 0])
    closer = int(np.sum(replaced & (rows[:, 1] < rows[:, 0])))
    return (f"the margins replace {int(replaced.sum())} of {len(rows)} priors ({closer} of them "
            f"closer to gt as completions); mean CD at init: as chosen {chosen.mean():.2f} mm, "
            f"all priors {rows[:, 0].mean():.2f}, the better of each {rows[:, :2].min(axis=1).mean():.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="+", type=Path)
    parser.add_argument("--iou-gain", type=float, default=ChoiceMargins.iou_gain)
    parser.add_argument("--ucd-gain-mm", type=float, default=ChoiceMargins.ucd_gain_mm)
    parser.add_argument("--free-space-slack", type=float, default=ChoiceMargins.free_space_slack)
    parser.add_argument("--large-iou-gain", type=float, default=ChoiceMargins.large_iou_gain)
    parser.add_argument("--set", dest="init_set", action="append", default=[],
                        metavar="KEY=VALUE", help="another init option, for both runs")
    args = parser.parse_args()
    margins = ChoiceMargins(args.iou_gain, args.ucd_gain_mm, args.free_space_slack,
                            args.large_iou_gain)
    print("| scene | id | prior IoU / UCD / free | completion IoU / UCD / free "
          "| alone on the table: prior / completion moved mm, turned deg, COM drop mm "
          "| lowest point above the table: prior / completion mm | CD prior [mm] "
          "| CD completion [mm] | auto chooses | better against gt |")
    print("|---|---:|---|---|---|---|---:|---:|---|---|")
    by_rest: list[tuple[float, float]] = []  # (CD prior, CD completion) the rest rule swaps
    chosen_cd: list[tuple[float, float, bool]] = []  # (CD prior, CD completion, replaced)
    for root in args.scenes:
        with_prior = _init(root, "prior", args.init_set)
        completed = _init(root, "completion", args.init_set)
        for i in sorted(with_prior):
            cd_p, rec, low_p = with_prior[i]
            if rec["prior"] is None or rec["completion"] is None:
                print(f"| {root.name} | {i} | - | not completed | - | {low_p:.1f} / - "
                      f"| {cd_p:.1f} | - | prior | - |")
                continue
            cd_c = completed[i][0] if i in completed else float("nan")
            low_c = completed[i][2] if i in completed else float("nan")
            p, c = ViewScore(**rec["prior"]), ViewScore(**rec["completion"])
            alone = rec.get("rest_alone")
            rest = None if alone is None else tuple(
                Rest.from_dict(alone[k]) for k in ("prior", "completion"))
            chosen, _ = choose(p, c, margins, rest)
            if chosen != choose(p, c, margins)[0]:
                by_rest.append((cd_p, cd_c))
            best = "completion" if cd_c < cd_p else "prior"
            chosen_cd.append((cd_p, cd_c, chosen == "completion"))
            rest_txt = "not alone" if alone is None else " / ".join(
                f"{alone[k]['moved_mm']:.0f}, {alone[k]['turned_deg']:.0f}, "
                f"{alone[k].get('com_drop_mm', float('nan')):.1f}"
                for k in ("prior", "completion"))
            print(f"| {root.name} | {i} | {p.iou:.2f} / {p.ucd_mm:.1f} / {p.free_space:.3f} "
                  f"| {c.iou:.2f} / {c.ucd_mm:.1f} / {c.free_space:.3f} | {rest_txt} "
                  f"| {low_p:.1f} / {low_c:.1f} "
                  f"| {cd_p:.1f} | {cd_c:.1f} | {chosen} | {best} |", flush=True)
    if chosen_cd:
        print("\n" + _summary(np.array(chosen_cd, dtype=float)))
    if by_rest:
        cd = np.array(by_rest)
        print(f"\nthe rest rule alone replaces {len(cd)} priors ({int(np.sum(cd[:, 1] < cd[:, 0]))} "
              f"of them closer to gt as completions); mean CD at init {cd[:, 0].mean():.2f} -> "
              f"{cd[:, 1].mean():.2f} mm")


if __name__ == "__main__":
    main()
