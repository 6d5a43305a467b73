#!/usr/bin/env python
"""Which scenes have a carrier whose top is hidden by what it carries? One line per find.

Runs r2s/geometry/hidden_carrier.py's test on each scene's init/ output (the observed
points init saved, its support plane) and input/camera.json, for the objects init
completed (a registered prior keeps its shape). Where gt/ exists, the line also gives the
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

from r2s.geometry.hidden_carrier import hidden_tops  # noqa: E402


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
    camera = json.loads((scene / "input" / "camera.json").read_text())
    point, normal = (np.asarray(state["support"][k], dtype=np.float64)
                     for k in ("point", "normal"))
    points = {o["id"]: np.load(scene / "init" / o["observed_points"])
              for o in state["objects"] if o.get("observed_points")}
    completed = {o["id"] for o in state["objects"] if o["source"] == "completed"}
    tops = hidden_tops(points, point, normal, np.asarray(camera["world_from_camera"])[:3, 3],
                       carriers=completed)
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
