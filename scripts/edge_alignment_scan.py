#!/usr/bin/env python
"""Where do the depth image's edges lie against the masks' outlines? One line per scene.

Runs r2s/diagnose/stats/edge_alignment.py's test on each scene's input/ (depth.png and
masks.png as they are), or with the depth image first moved ``--shift-px`` pixels to the
right (the columns it uncovers read nothing) or turned ``--turn-deg`` degrees about the
image centre (clockwise as shown; what turns in from outside reads nothing), which is how
the thresholds of that test were measured (docs/diagnose.md, section 6). Nothing is
written.

Usage:
  python scripts/edge_alignment_scan.py SCENE [SCENE ...] [--shift-px 3] [--turn-deg 1.5]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.diagnose.stats.edge_alignment import test_edge_alignment  # noqa: E402
from r2s.io.input_scene import load_input  # noqa: E402
from r2s.synth.depth_registration import turned_about_centre  # noqa: E402


def moved_right(depth_m: np.ndarray, shift_px: int) -> np.ndarray:
    """(H, W) depth moved ``shift_px`` columns to the right; the uncovered columns NaN."""
    if shift_px <= 0:
        return depth_m
    out = np.full_like(depth_m, np.nan)
    out[:, shift_px:] = depth_m[:, :-shift_px]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="+", type=Path)
    ap.add_argument("--shift-px", type=int, default=0)
    ap.add_argument("--turn-deg", type=float, default=0.0)
    args = ap.parse_args()
    shifts = []
    for root in args.scenes:
        scene = load_input(root)
        depth = turned_about_centre(moved_right(scene.depth_m, args.shift_px), args.turn_deg)
        found = test_edge_alignment(depth, scene.masks)
        if found is None:
            print(f"{root}: fewer than 3 objects with outlines on depth edges")
            continue
        shifts.append(max(abs(v) for v in found.shift_px))
        print(f"{root}: shift ({found.shift_px[0]:+.2f}, {found.shift_px[1]:+.2f}) px, "
              f"agreement {found.agreement:.2f} of {len(found.peaks_px)} objects, "
              f"turn {found.turn_deg:+.2f} deg (sd {found.turn_sd_deg:.2f}, count "
              f"x{found.turn_gain:.3f}), "
              f"reported: {'yes' if found.structured else 'no'}"
              f"{' (turn)' if found.turn_structured else ''}")
    if shifts:
        print(f"{len(shifts)} scenes: largest |shift| {min(shifts):.2f}-{max(shifts):.2f} px")


if __name__ == "__main__":
    main()
