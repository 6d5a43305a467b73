#!/usr/bin/env python
"""How r2s's fragment merge (r2s/geometry/mask_fragments.py) does on synthetic scenes
whose segmenter errors are recorded in ``gt/scene.json["realism"]["masks"]``.

For every extra id (a split piece or a sliver; ``extra_ids``: new id -> its object) it
says whom the merge joined it with: its object (whichever of the two ids is kept), only
another piece of the same object, another object (wrong), or nothing (missed); and it
counts merges of two different objects' ids, and how often a joined piece is reconstructed
under its object's own (declared) id. Ids with a prior are protected, as in ``scene_model.corrected_input``.

Usage:
  for s in $(seq 10 21); do r2s synth scenes/s$s --seed $s --count 6 \\
      --set realism=realsense --set prior_model=none; done
  python scripts/check_mask_fragments.py scenes/s*
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.geometry.mask_fragments import fragment_parents  # noqa: E402
from r2s.io.input_scene import load_input  # noqa: E402
from r2s.scene_model import declared_labels  # noqa: E402


def check(scene: Path, occluded: bool = True) -> dict[str, int]:
    view = load_input(scene)
    gt = json.loads((scene / "gt" / "scene.json").read_text())
    extra = {int(k): int(v) for k, v in
             gt.get("realism", {}).get("masks", {}).get("extra_ids", {}).items()}
    protected = [o.id for o in view.objects if o.prior_mesh is not None]
    declared = [o.id for o in view.objects if o.declared]
    parents = fragment_parents(view.masks, view.depth_m, view.rgb, protected, declared,
                               view.camera.K if occluded else None,
                               labels=declared_labels(view))

    def owner(i: int) -> int:
        return extra.get(i, i)  # the gt object an id belongs to

    def root(i: int) -> int:
        return parents[i][0] if i in parents else i  # the id it is reconstructed as

    counts = {"extra ids": len(extra), "with its object": 0, "only with a sibling piece": 0,
              "with another object": 0, "missed": 0, "different objects merged": 0,
              "joined under the object's own id": 0}
    for frag, (par, _) in parents.items():
        if owner(frag) != owner(par):
            counts["different objects merged"] += 1
    ids = set(view.ids)
    for i, obj in sorted(extra.items()):
        group = {j for j in ids if root(j) == root(i)} - {i}
        if obj in group:
            counts["with its object"] += 1
            counts["joined under the object's own id"] += int(root(i) == obj)
        elif any(owner(j) != obj for j in group):
            counts["with another object"] += 1
        elif group:
            counts["only with a sibling piece"] += 1
        else:
            counts["missed"] += 1
    return counts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="+", type=Path)
    ap.add_argument("--no-occluded", action="store_true",
                    help="the boundary test only (no pieces joined across an occluder)")
    args = ap.parse_args()
    total: dict[str, int] = {}
    for scene in args.scenes:
        counts = check(scene, occluded=not args.no_occluded)
        print(f"{scene.name}: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
        for k, v in counts.items():
            total[k] = total.get(k, 0) + v
    print(f"all {len(args.scenes)} scenes: " + ", ".join(f"{k} {v}" for k, v in total.items()))


if __name__ == "__main__":
    main()
