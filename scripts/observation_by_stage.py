#!/usr/bin/env python
"""Which stage loses the observation? Observation metrics of each state stage of a scene.

For each scene and each state stage that ran (init, geomopt, physopt, texture): pooled
silhouette IoU, the worst IoU over objects with >= 1000 mask pixels, mean free-space
violation and mean UCD against the input view (r2s/metrics/observation.py), plus the
stability, IoU, free space and UCD of export/ as evaluate/metrics.json reports them.

Usage:
  python scripts/observation_by_stage.py SCENE [SCENE ...] [--objects]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.io.input_scene import load_input  # noqa: E402
from r2s.io.mesh_io import load_mesh  # noqa: E402
from r2s.io.paths import ScenePaths  # noqa: E402
from r2s.io.state import read_state  # noqa: E402
from r2s.metrics.observation import observe_scene  # noqa: E402
from r2s.scene_model import corrected_input, corrected_state  # noqa: E402
from r2s.io.manifest import load_manifest  # noqa: E402

STAGES = ("init", "geomopt", "physopt", "texture")


def _fmt(v: object, digits: int = 3) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def scene_rows(root: Path, per_object: bool = False) -> list[list[str]]:
    paths = ScenePaths(root)
    model = load_manifest(paths.manifest).model
    view = corrected_input(load_input(root), model)
    rows = []
    for stage in STAGES:
        if not (paths.stage_dir(stage) / "state.json").is_file():
            continue
        state = corrected_state(read_state(paths.stage_dir(stage)), model)
        meshes = [load_mesh(paths.stage_dir(stage) / o.mesh).apply_transform(o.pose)
                  for o in state.objects]
        seen = observe_scene(meshes, [o.id for o in state.objects], view.camera.K,
                             view.camera.world_from_camera, view.depth_m, view.masks)
        s = seen.summary()
        rows.append([root.name, stage, "", _fmt(s["silhouette_iou"]),
                     _fmt(s["min_silhouette_iou"]), _fmt(s["free_space_violation"]),
                     _fmt(s["ucd_mm"], 2)])
        if per_object:
            source = {o.id: o.source for o in state.objects}
            rows[-1].append(" ".join(f"{ob.id}({source[ob.id][0]}):{_fmt(ob.iou, 2)}"
                                     for ob in seen.objects))
    metrics = paths.stage_dir("evaluate") / "metrics.json"
    if metrics.is_file():
        m = json.loads(metrics.read_text())
        rows.append([root.name, "export", _fmt(m.get("stability_ratio"), 2),
                     _fmt(m.get("silhouette_iou")), _fmt(m.get("min_silhouette_iou")),
                     _fmt(m.get("free_space_violation")), _fmt(m.get("ucd_mm"), 2)])
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="+", type=Path)
    parser.add_argument("--objects", action="store_true",
                        help="add each object's IoU per stage (id(p = prior, c = completed))")
    args = parser.parse_args()
    header = ["scene", "stage", "stable", "IoU", "min IoU", "free space", "UCD mm"]
    if args.objects:
        header.append("IoU per object")
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for root in args.scenes:
        for row in scene_rows(root, args.objects):
            if args.objects and len(row) < len(header):
                row = row + [""]
            print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
