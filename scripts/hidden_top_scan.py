#!/usr/bin/env python
"""Which scenes have a carrier whose top is hidden by what it carries? One line per find.

Runs init's search for hidden tops (r2s/geometry/hidden_carrier.py on the observed points
as init cleans them) on each scene's input/ with the support plane init/ fitted, for the
objects without a prior (a registered prior keeps its shape). Where gt/ exists, the line also gives the
share of the hidden top's points, 5 mm under it, that lie inside the carrier's true mesh
(1.0: the truth does carry the other object there). Scenes with no find print nothing;
the last line counts the scenes read. Nothing is written.

Usage:
  python scripts/hidden_top_scan.py SCENE [SCENE ...]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.geometry.plane import PlaneFit  # noqa: E402
from r2s.io.input_scene import load_input  # noqa: E402
from r2s.io.manifest import load_manifest  # noqa: E402
from r2s.scene_model import corrected_input  # noqa: E402
from r2s.stages.init import Options, _hidden_tops, _object_points  # noqa: E402


def _truth_share(scene: Path, carrier: int, points_world: np.ndarray,
                 normal: np.ndarray) -> float | None:
    """Share of ``points_world`` (M, 3) moved 5 mm along -``normal`` inside the carrier's
    gt mesh, or None without gt/."""
    gt = scene / "gt" / "scene.json"
    if not gt.exists():
        return None
    import trimesh
    for obj in json.loads(gt.read_text())["objects"]:
        if obj["id"] == carrier:
            mesh = trimesh.load(scene / "gt" / obj["mesh"], force="mesh")
            mesh.apply_transform(np.asarray(obj["world_from_object"]))
            return float(mesh.contains(points_world - 0.005 * normal).mean())
    return None


def scan(scene: Path) -> list[str]:
    state = json.loads((scene / "init" / "state.json").read_text())
    point, normal = (np.asarray(state["support"][k], dtype=np.float64)
                     for k in ("point", "normal"))
    plane = PlaneFit(point=point, normal=normal, inliers=np.zeros(0, dtype=bool))
    options = Options()
    manifest = scene / "manifest.json"
    model = load_manifest(manifest).model if manifest.exists() else None
    data = corrected_input(load_input(scene), model)  # as init reads it: fragments merged
    observed = {spec.id: _object_points(data, spec.id, options, plane) for spec in data.objects}
    tops = _hidden_tops(data, observed, plane, options)
    lines = []
    for carrier, top in sorted(tops.items()):
        share = _truth_share(scene, carrier, top.points_world, normal / np.linalg.norm(normal))
        truth = "" if share is None else f", inside the true carrier: {share:.2f}"
        lines.append(f"{scene}: object {carrier} carries {top.carried_id}, hidden top at "
                     f"{1000 * top.height_m:.0f} mm, {len(top.points_world)} points{truth}")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="+", type=Path)
    args = parser.parse_args()
    read = 0
    for scene in args.scenes:
        if not (scene / "init" / "state.json").exists():
            continue
        read += 1
        for line in scan(scene):
            print(line)
    print(f"{read} scenes read")


if __name__ == "__main__":
    main()
