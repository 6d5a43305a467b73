#!/usr/bin/env python
"""Could physopt's whole-scene checks stop earlier? Records every check's rollout and tries
a stopping rule on it.

A check (r2s/physopt/pybullet_world.py, ``drift``) follows the scene for 5 s and stops
early only once every body has stayed under ``REST_SPEED_MPS`` and ``REST_SPIN_RADPS`` for
``REST_WINDOW_S`` and survives the nudge probe. This script runs physopt on a scene
(in place: give it a copy that has geomopt/) with every check recorded: each body's COM
position and orientation every ``REST_POLL_STEPS`` steps, single-threaded. It then replays a
rule that stops on *net* motion instead: every body's COM stays within ``--window-mm``
and its orientation within ``--window-deg`` over the last ``--window-polls`` polls, plus the
1 s probe the check runs before stopping. It prints the steps the rule would save and the
checks whose moving set or failing set would change, by physopt's own tests and default
settings (``RepairSettings.moving``: over 5 mm or 2 deg; ``severities`` >= 1: the judge's
50 mm or 5 deg).

Usage: python scripts/check_rest_rules.py COPY [--window-mm 0.1,0.5 --window-deg 0.057,0.3]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import pybullet as pb  # noqa: E402

import r2s.physopt.pybullet_world as pw  # noqa: E402
import r2s.physopt.repair as repair  # noqa: E402
from r2s.physopt.repair import severities  # noqa: E402
from r2s.physopt.settings import RepairSettings  # noqa: E402
from r2s.metrics.stability import rotation_angle_deg  # noqa: E402

SETTINGS = RepairSettings()
"""physopt's defaults: what counts as moving (``moving``) and as failing (``severities``)."""


def recording_drift(records: list) -> Callable:
    """``pw.drift`` that also keeps, per poll, each body's COM (3,) and rotation (3, 3)
    (world frame), and the steps it ran, the nudge probe's included."""
    original = pw.drift

    def drift(world, start, duration_s, time_step_s=1.0 / 240.0, stop_at_rest=True):
        polls = []
        original_step = pb.stepSimulation

        def step(*args, **kwargs):
            out = original_step(*args, **kwargs)
            step.count += 1
            if step.count % pw.REST_POLL_STEPS == 0 and not step.probing:
                poses = world.poses()
                polls.append({i: (pw.com_world(p, world.coms[i]), p[:3, :3])
                              for i, p in poses.items()})
            return out
        step.count, step.probing = 0, False
        original_probe = pw._rest_survives_nudge

        def probe(*args, **kwargs):
            step.probing = True
            try:
                return original_probe(*args, **kwargs)
            finally:
                step.probing = False
        pw.pb.stepSimulation, pw._rest_survives_nudge = step, probe
        began = time.perf_counter()
        try:
            out = original(world, start, duration_s, time_step_s, stop_at_rest)
        finally:
            pw.pb.stepSimulation, pw._rest_survives_nudge = original_step, original_probe
        starts = {i: (pw.com_world(p, world.coms[i]), p[:3, :3]) for i, p in start.items()}
        records.append({"polls": polls, "start": starts, "out": out, "steps": step.count,
                        "seconds": time.perf_counter() - began})
        return out
    return drift


def drift_at(poll: dict, start: dict) -> dict:
    return {i: (float(np.linalg.norm(c - start[i][0])), float(rotation_angle_deg(start[i][1], r)))
            for i, (c, r) in poll.items()}


def moving(drifts: dict) -> set:
    return set(SETTINGS.moving(drifts))


def failing(drifts: dict) -> set:
    return {i for i, s in severities(drifts, SETTINGS).items() if s >= 1.0}


def replay(records: list, polls: int, window_m: float, window_deg: float) -> None:
    probe_steps = int(round(pw.PROBE_S * 240))
    total = saved = fired = moving_changed = failing_changed = 0
    for rec in records:
        total += rec["steps"]
        for k in range(polls - 1, len(rec["polls"])):
            win = rec["polls"][k - polls + 1:k + 1]
            still = all(np.linalg.norm(p[i][0] - win[0][i][0]) <= window_m
                        and rotation_angle_deg(win[0][i][1], p[i][1]) <= window_deg
                        for p in win for i in p)
            stop = (k + 1) * pw.REST_POLL_STEPS + probe_steps
            if still and stop < rec["steps"]:
                fired += 1
                saved += rec["steps"] - stop
                early = drift_at(rec["polls"][k], rec["start"])
                moving_changed += moving(early) != moving(rec["out"])
                failing_changed += failing(early) != failing(rec["out"])
                break
    print(f"checks {len(records)}, steps {total}; the rule stops {fired} checks early and "
          f"saves {saved} steps ({100 * saved / max(total, 1):.0f} %); moving set changed in "
          f"{moving_changed}, failing set in {failing_changed}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", type=Path, help="a copy of a scene with geomopt/ (rewritten)")
    ap.add_argument("--window-polls", type=int, default=10)
    ap.add_argument("--window-mm", default="0.1",
                    help="COM window, mm; a comma-separated list tries several rules")
    ap.add_argument("--window-deg", default="0.057",
                    help="orientation window, degrees, one per --window-mm entry")
    args = ap.parse_args()
    os.environ["OMP_NUM_THREADS"] = "1"  # every check in this process, so it is recorded
    records: list = []
    repair.drift = recording_drift(records)
    from r2s.runner.pipeline import run_single_stage
    run_single_stage(args.scene, "physopt", {})
    seconds = sum(r["seconds"] for r in records)
    print(f"{len(records)} checks took {seconds:.0f} s for {sum(r['steps'] for r in records)} "
          f"steps ({1000 * seconds / max(sum(r['steps'] for r in records), 1):.2f} ms a step)")
    for mm, deg in zip(args.window_mm.split(","), args.window_deg.split(",")):
        print(f"COM within {mm} mm and orientation within {deg} deg over "
              f"{args.window_polls} polls:")
        replay(records, args.window_polls, 1e-3 * float(mm), float(deg))


if __name__ == "__main__":
    main()
