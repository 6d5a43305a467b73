#!/usr/bin/env python
"""Stable fraction of the same export judged in PyBullet (scene.json) and in MuJoCo
(export/scene.xml), with the same criterion (``r2s evaluate`` and ``r2s evaluate --set
engine=mujoco``: 3 s, COM < 5 cm and rotation < 5 deg).

For each scene (already run, e.g. by ``r2s run SCENE --skip texture``) the script runs
evaluate once per engine (``--export`` reruns export first, to judge this code's scene.xml)
and prints one row per scene, the pooled row, and the objects the engines disagree on.

Usage:
  python scripts/compare_engines.py SCENE [SCENE ...] [--export] [--name NAME --out DOC]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.io.paths import ScenePaths  # noqa: E402
from r2s.runner.base import run_stage  # noqa: E402
from r2s.runner.pipeline import build_options  # noqa: E402
from r2s.runner.registry import get_stage  # noqa: E402

ENGINES = ("pybullet", "mujoco")


def _run(scene: Path, name: str, overrides: dict) -> None:
    spec = get_stage(name)
    run_stage(spec, scene, build_options(spec, None, overrides), force=True)


def judge(scene: Path) -> dict[str, list[dict]]:
    """Per engine, evaluate's per-object records (id, stable, drifts)."""
    out = {}
    for engine in ENGINES:
        _run(scene, "evaluate", {"engine": engine, "render": "false"})
        out[engine] = json.loads(ScenePaths(scene).metrics.read_text())["objects"]
    return out


def _pct(n: int, total: int) -> str:
    return f"{100.0 * n / total:.1f} % ({n}/{total})" if total else "-"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("scenes", nargs="+", type=Path)
    ap.add_argument("--export", action="store_true", help="rerun export before judging")
    ap.add_argument("--name", default="compare_engines", help="doc block name")
    ap.add_argument("--out", type=Path, default=None, help="markdown file for the table")
    args = ap.parse_args()
    lines = ["| Scene | Objects | Stable, PyBullet | Stable, MuJoCo | Judged differently "
             "(id: PyBullet / MuJoCo drift) |", "|---|---:|---:|---:|---|"]
    totals = {e: 0 for e in ENGINES}
    n_all = 0
    for scene in args.scenes:
        if args.export:
            _run(scene, "export", {})
        objs = judge(scene)
        n = len(objs["pybullet"])
        stable = {e: sum(o["stable"] for o in objs[e]) for e in ENGINES}
        differ = [f"{a['id']}: {1e3 * a['translation_drift_m']:.1f} mm "
                  f"{a['rotation_drift_deg']:.1f} deg / {1e3 * b['translation_drift_m']:.1f} mm "
                  f"{b['rotation_drift_deg']:.1f} deg"
                  for a, b in zip(objs["pybullet"], objs["mujoco"]) if a["stable"] != b["stable"]]
        lines.append(f"| {scene.name} | {n} | {_pct(stable['pybullet'], n)} | "
                     f"{_pct(stable['mujoco'], n)} | {'; '.join(differ) or '-'} |")
        print(lines[-1], flush=True)
        for e in ENGINES:
            totals[e] += stable[e]
        n_all += n
    lines.append(f"| all | {n_all} | {_pct(totals['pybullet'], n_all)} | "
                 f"{_pct(totals['mujoco'], n_all)} | |")
    table = "\n".join(lines) + "\n"
    print(table)
    if args.out:
        sys.path.insert(0, str(REPO / "scripts"))
        from doc_block import write_generated_block

        write_generated_block(args.out, args.name, table)


if __name__ == "__main__":
    main()
