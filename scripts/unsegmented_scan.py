"""How well init finds unmasked objects on the table (r2s/geometry/unsegmented.py).

For each scene (after ``r2s init``: the support comes from init's state): the regions
found with the masks as given (false alarms, when every object is masked), and, with
``--each``, the regions found with each instance removed from the masks in turn (in
memory), with the instance's pixel count.

Usage::

    python scripts/unsegmented_scan.py bench/s_A/*/            # false alarms
    python scripts/unsegmented_scan.py --each bench/s_A/*_noprior/
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from r2s.geometry.unsegmented import unsegmented_regions
from r2s.io.input_scene import load_input
from r2s.scene_model import corrected_input


def _found(scene, support, masks, min_area_px):
    cam = scene.camera
    return unsegmented_regions(scene.depth_m, cam.K, cam.world_from_camera, masks,
                               support["point"], support["normal"], min_area_px=min_area_px)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="+", type=Path)
    ap.add_argument("--each", action="store_true", help="unmask each instance in turn")
    ap.add_argument("--min-area-px", type=int, default=None,
                    help="smallest region (default: the module's rule)")
    args = ap.parse_args()
    alarms = found = tried = big = big_found = 0
    for root in args.scenes:
        state = root / "init" / "state.json"
        if not state.is_file():
            print(f"{root}: no init state, skipped")
            continue
        manifest = root / "manifest.json"
        model = json.loads(manifest.read_text()).get("model") if manifest.is_file() else None
        scene = corrected_input(load_input(root), model)
        support = json.loads(state.read_text())["support"]
        regions = _found(scene, support, scene.masks, args.min_area_px)
        alarms += bool(regions)
        print(f"{root}: as masked: {[(r.area_px, round(1000 * r.height_m)) for r in regions]}")
        if not args.each:
            continue
        for i in scene.ids:
            masks = scene.masks.copy()
            area = int((masks == i).sum())
            masks[masks == i] = 0
            regions = _found(scene, support, masks, args.min_area_px)
            tried += 1
            found += bool(regions)
            big += area >= 1000
            big_found += area >= 1000 and bool(regions)
            print(f"  instance {i} ({area} px) unmasked: "
                  f"{[(r.area_px, round(1000 * r.height_m), r.touching_ids) for r in regions]}")
    print(f"scenes with a region as masked: {alarms} of {len(args.scenes)}")
    if args.each:
        print(f"unmasked instances found: {found} of {tried}; "
              f"of those with >= 1000 px: {big_found} of {big}")


if __name__ == "__main__":
    main()
