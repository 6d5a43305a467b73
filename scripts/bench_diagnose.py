#!/usr/bin/env python
"""Benchmark of ``r2s diagnose``: inject each effect with ``r2s synth``, see if it is found.

For every case (an effect at a realistic size, or none) and seed: synthesise a YCB scene
with the effect recorded only in gt/, run the pipeline stages, run ``diagnose`` (which
reruns the affected stages on a copy with the effect in the model), and tabulate: was the
effect named first, the fitted size against the injected one, and the ground-truth error
before -> after. Friction is only identifiable from an interaction, so its scenes get an
observed strike (``input/interaction/``, docs/interaction.md) made on the ground truth.
A COM offset is only visible when the rest pose needs it, so COM scenes are drawn (up to
COM_TRIES synth seeds) until the shifted object, given back its uniform COM, moves in the
ground truth and is not ball-like (a ball's orientation is not seen: its COM only steadies
it).

Usage (regenerates the table in docs/diagnose.md between its bench markers):
  python scripts/bench_diagnose.py --seeds 1 --clean 2 --out docs/diagnose.md
Scenes live in bench/diagnose/<case>_s<seed> and are reused; per-scene results are kept
in <scene>/bench_diagnose.json, so ``--table-only`` rebuilds the table without running.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any, Optional

import numpy as np
from scipy.spatial.transform import Rotation

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "scripts"))

from doc_block import write_generated_block  # noqa: E402
from r2s.io.paths import ScenePaths  # noqa: E402
from r2s.runner.pipeline import build_options  # noqa: E402
from r2s.runner.base import run_stage  # noqa: E402
from r2s.runner.registry import get_stage  # noqa: E402

ORACLE_CASES = ("com_offset", "friction")
"""Cases also run with the true geometry (``--oracle``): physical effects need a
reconstruction that rests where the truth rests."""

CASES: dict[str, tuple[dict[str, str], Optional[str]]] = {
    "clean": ({}, None),
    "depth_scale": ({"depth_scale": "1.03"}, "depth_scale"),
    "depth_offset": ({"depth_offset_m": "0.01"}, "depth_offset"),
    "camera_rotation": ({"camera_rotation_deg": "2.5"}, "camera_rotation"),
    "table_tilt": ({"table_tilt_deg": "2.5"}, "table_tilt"),
    "com_offset": ({"com_offset_m": "0.02"}, "com_offset"),
    "friction": ({"friction": "0.3"}, "friction"),
}
"""case -> (synth effects, the effect diagnose should name first)."""

# ---- scenes ------------------------------------------------------------------------------

COM_TRIES = 24
"""A COM offset shows only when the rest pose needs it: synth seeds tried per COM scene
(few draws qualify: one in 5 and none in 8 in the last table; a scene kept after the last try
without qualifying is marked "not observable in gt" in the table)."""


def make_scene(root: Path, case: str, seed: int, count: int) -> Path:
    import shutil

    from r2s.synth.generate import SynthOptions, synthesize

    scene = root / f"{case}_s{seed}"
    tries = COM_TRIES if case == "com_offset" else 1
    for k in range(tries):
        if (scene / "gt" / "scene.json").is_file():
            break
        t0 = time.perf_counter()
        synthesize(scene, SynthOptions(objects="ycb", count=count, seed=1000 * (k + 1) + seed,
                                       effects=CASES[case][0]))
        print(f"synth {scene.name} (seed {1000 * (k + 1) + seed}): "
              f"{time.perf_counter() - t0:.0f} s", flush=True)
        if case == "com_offset" and not com_offset_observable(scene):
            print(f"  {scene.name}: the shifted COM does not change the rest pose; next seed",
                  flush=True)
            if k + 1 < tries:
                shutil.rmtree(scene)
    if case == "friction" and not has_observed_push(scene):
        write_observed_push(scene)
    return scene


def gt_world(scene: Path, com_override: Optional[dict] = None):
    """The ground truth as PyBullet bodies (``com_override``: id -> COM in object frame)."""
    from r2s.diagnose.measure.observe import ObjectModel, world_spec
    from r2s.io.mesh_io import load_mesh
    from r2s.io.scene_json import read_gt_scene

    paths = ScenePaths(scene)
    gt = read_gt_scene(paths.gt_scene)
    com_override = com_override or {}
    objects = [ObjectModel(o.id, o.label, load_mesh(paths.gt / o.mesh),
                           np.asarray(o.world_from_object), None, o.mass_kg,
                           np.asarray(com_override.get(o.id, o.com_in_object)), o.friction)
               for o in gt.objects]
    return gt, world_spec(objects, gt.support.point, gt.support.normal, gt.support.friction,
                          paths.convex_cache)


def com_offset_observable(scene: Path) -> bool:
    """Does the shifted object topple or rock in the ground truth with its COM put back
    (uniform)? A round object on a point contact is left out: its orientation is not seen,
    so an offset COM only steadies it, and that shows as no particular pose."""
    from r2s.diagnose.data import PhysicsModel
    from r2s.diagnose.measure.physics import rollout_motion
    from r2s.io.scene_json import read_gt_scene

    gt = read_gt_scene(ScenePaths(scene).gt_scene)
    recs = ((gt.model_extra or {}).get("injected_effects") or {}).get("com_offset_m", {})
    uniform = {r["id"]: r["original_com_in_object"] for r in recs.get("objects", [])}
    if not uniform:
        return False
    _, spec = gt_world(scene, uniform)
    motion = rollout_motion(spec, PhysicsModel(gravity=np.asarray(gt.gravity)), 1.0)
    for i in uniform:
        if not is_round(spec.body(i).mesh) and (motion[i].translation_norm_m > 0.01
                                                or np.degrees(motion[i].angle_rad) > 5.0):
            return True
    return False


def is_round(mesh) -> bool:
    """Ball-like (a fruit, a ball): extents within 15 % and most of the bounding sphere
    filled; its orientation cannot be seen and it rolls on a point."""
    ext = np.asarray(mesh.extents)
    r = 0.5 * float(ext.mean())
    filled = abs(float(mesh.volume)) / (4.0 / 3.0 * np.pi * r ** 3)
    return bool(ext.min() > 0.85 * ext.max() and filled > 0.75)


STRIKE = dict(speed_mps=0.6, travel_m=0.02, approach_m=0.03, radius_m=0.01, settle_s=1.0)
"""A strike rather than a slow push: the struck object slides on after the pusher stops,
as far as its friction lets it, which is what makes friction identifiable."""


def has_observed_push(scene: Path) -> bool:
    """``input/interaction/`` in the layout of docs/interaction.md (not the old push.json)."""
    push = scene / "input" / "interaction" / "push.json"
    return push.is_file() and "pusher" not in json.loads(push.read_text())


def write_observed_push(scene: Path) -> None:
    """Strike one object of the ground truth and record what the camera saw after it
    (``r2s.synth.push``: input/interaction/ and gt/push.json).

    The struck object is the one on the table whose strike moves it most while moving the
    others least (a push that topples a stack says little about friction), among objects
    that are not ball-like (a rolling ball says little about friction either).
    """
    from r2s.synth.push import PushSettings, add_observed_push

    add_observed_push(scene, PushSettings(**STRIKE))


def oracle_geometry(scene: Path) -> None:
    """Replace the geomopt state by the true shapes and poses, with what a geometric
    reconstruction cannot know left at its defaults (uniform density, default friction),
    then export and evaluate again. Separates the diagnosis of physical effects from the
    quality of the upstream geometry."""
    import shutil

    from pydantic import BaseModel

    from r2s.io.scene_json import read_gt_scene
    from r2s.io.state import ObjectState, SceneState, SupportPlane, write_state
    from r2s.runner.base import StageOptions, StageSpec

    paths = ScenePaths(scene)
    gt = read_gt_scene(paths.gt_scene)
    visible = {o.id for o in gt.objects if (o.model_extra or {}).get("in_input", True)}

    def run(ctx) -> dict:
        (ctx.out_dir / "meshes").mkdir(parents=True)
        objects = []
        for o in gt.objects:
            if o.id not in visible:
                continue
            shutil.copy(paths.gt / o.mesh, ctx.out_dir / "meshes" / f"{o.id}.glb")
            objects.append(ObjectState(id=o.id, label=o.label, mesh=f"meshes/{o.id}.glb",
                                       world_from_object=o.world_from_object, source="prior"))
        write_state(ctx.out_dir, SceneState(
            stage="geomopt", gravity=list(gt.gravity),
            support=SupportPlane(point=gt.support.point, normal=gt.support.normal,
                                 friction=gt.support.friction), objects=objects))
        return {"oracle": True}

    class Oracle(StageOptions):
        pass

    spec = StageSpec("geomopt", Oracle, lambda p, o, m: [p.gt], run)
    run_stage(spec, scene, Oracle(), force=True)
    for name in ("export", "evaluate"):
        stage = get_stage(name)
        run_stage(stage, scene, build_options(stage, None, {}), force=True)


def run_pipeline(scene: Path, stages: list[str]) -> None:
    for name in stages:
        spec = get_stage(name)
        t0 = time.perf_counter()
        res = run_stage(spec, scene, build_options(spec, None, {}), force=False)
        if res.ran:
            print(f"  {scene.name} {name}: {time.perf_counter() - t0:.0f} s", flush=True)


# ---- one row -----------------------------------------------------------------------------

def injected_size(case: str, injected: dict) -> tuple[Optional[float], str]:
    """The injected size in the units diagnose fits (observable part where it matters)."""
    rec = injected.get({"depth_scale": "depth_scale", "depth_offset": "depth_offset_m",
                        "camera_rotation": "camera_rotation_deg",
                        "table_tilt": "table_tilt_deg", "com_offset": "com_offset_m",
                        "friction": "friction"}.get(case, ""), None)
    if rec is None:
        return None, ""
    if case == "camera_rotation":
        true = np.asarray(rec["true_world_from_camera"])[:3, :3]
        written = np.asarray(rec["written_world_from_camera"])[:3, :3]
        q = written @ true.T  # the declared world = q (true world) about the camera
        tilt = np.degrees(np.arccos(np.clip((q @ [0, 0, 1.0])[2], -1, 1)))
        return float(tilt), f"{rec['value']} deg (tilting part {tilt:.2f})"
    if case == "com_offset":
        dist = [o["distance_m"] for o in rec.get("objects", [])]
        return (float(dist[0]) if dist else None), f"{rec['value']} m (applied {dist})"
    return float(rec["value"]), str(rec["value"])


def fitted_size(case: str, chosen: Optional[dict], report: dict) -> Optional[float]:
    if chosen is None:
        return None
    params = chosen["params"]
    if case == "depth_scale":
        return params.get("scale")
    if case == "depth_offset":
        return params.get("offset_m")
    if case in ("camera_rotation", "table_tilt"):
        return params.get("angle_deg")
    if case == "com_offset":
        shifts = [np.linalg.norm(e["shift_world_m"]) for e in params.get("objects", {}).values()]
        return float(max(shifts)) if shifts else None
    if case == "friction":
        mus = [e["friction"] for e in params.get("objects", {}).values()]
        return float(mus[0]) if mus else None
    return None


def size_error(case: str, fitted: Optional[float], truth: Optional[float]) -> Optional[float]:
    """Relative error of the effect's size (for a depth scale: of s - 1)."""
    if fitted is None or truth is None:
        return None
    if case == "depth_scale":
        return abs(fitted - truth) / abs(truth - 1.0)
    return abs(fitted - truth) / abs(truth)


def headline_error(case: str, gt: dict, injected: dict, pushed: Optional[int] = None
                   ) -> tuple[str, Any]:
    """The ground-truth error the case's effect should reduce."""
    if case == "camera_rotation":
        return "support normal err (deg)", gt.get("state_support_normal_error_deg")
    if case == "table_tilt":
        return "table-gravity err (deg)", gt.get("table_gravity_error_deg")
    if case == "com_offset":
        ids = [o["id"] for o in injected.get("com_offset_m", {}).get("objects", [])]
        errs = [o["com_error_mm"] for o in gt.get("objects", []) if o["id"] in ids]
        return "COM err of shifted obj (mm)", errs[0] if errs else None
    if case == "friction":
        errs = [abs(o["friction"] - o["gt_friction"]) for o in gt.get("objects", [])
                if o["id"] == pushed]
        return "friction err of pushed obj", errs[0] if errs else None
    return "pose err, median (mm)", gt.get("state_centroid_error_median_mm")


def row(scene: Path, case: str, seed: int, seconds: float) -> dict:
    report = json.loads((scene / "diagnose" / "report.json").read_text())
    gt = report.get("gt_errors") or {}
    before, after = gt.get("before") or {}, gt.get("after") or {}
    injected = before.get("injected_effects") or {}
    expected = CASES[case][1]
    chosen = report["chosen"][0] if report["chosen"] else None
    truth, truth_text = injected_size(case, injected)
    fitted = fitted_size(case, chosen if chosen and chosen["effect"] == expected else None,
                         report)
    observed = scene / "input" / "interaction" / "observed.json"
    pushed = json.loads(observed.read_text()).get("pushed_id") if observed.is_file() else None
    name, err_before = headline_error(case, before, injected, pushed)
    _, err_after = headline_error(case, after, injected, pushed) if after else (name, None)
    ranking = [f for f in report["ranking"][0] if f["identifiable"]][:3]
    return {
        "scene": scene.name, "case": case, "seed": seed, "expected": expected,
        "injected": truth_text, "decision": report["decision"],
        "named_first": (report["decision"][:1] == [expected]) if expected else
        (report["decision"] == []),
        "ties": report["ties"][0] if report["ties"] else [],
        "ranking": [(f["effect"], round(f["score"], 1)) for f in ranking],
        "fitted": fitted, "truth": truth, "size_error": size_error(case, fitted, truth),
        "error_name": name, "error_before": err_before, "error_after": err_after,
        "centroid_before": before.get("centroid_error_mm"),
        "centroid_after": after.get("centroid_error_mm"),
        "chamfer_before": before.get("chamfer_mm"), "chamfer_after": after.get("chamfer_mm"),
        "stability_before": before.get("stability_ratio"),
        "stability_after": after.get("stability_ratio"),
        "residual_before": report["residual_total"]["before"],
        "residual_after": report["residual_total"]["after"],
        "rerun": report["rerun"]["stages"], "seconds": seconds,
    }


# ---- table -------------------------------------------------------------------------------

def _f(v: Any, fmt: str = "{:.3g}") -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return fmt.format(v)
    return str(v)


def table(rows: list[dict]) -> str:
    lines = [
        "| case (seed) | injected | named first | top of ranking (score) | fitted | "
        "size err | headline gt error: before -> after | centroid mm | CD mm | stability | "
        "residual SSE |",
        "| --- | --- | :---: | --- | --- | ---: | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        top = ", ".join(f"{n} {b}" for n, b in r["ranking"][:2])
        named = "yes" if r["named_first"] else f"no ({', '.join(r['decision']) or 'none'})"
        if r["ties"] and r["decision"]:
            named += f"; tie {'/'.join(r['ties'])}"
        label = f"{r['case']} ({r['seed']}{', true geometry' if r.get('oracle') else ''})"
        if r.get("observable") is False:
            label += " [not observable in gt]"
        lines.append(
            f"| {label} | {r['injected'] or '-'} | {named} | {top} | "
            f"{_f(r['fitted'], '{:.4g}')} | "
            f"{_f(None if r['size_error'] is None else 100 * r['size_error'], '{:.0f}')}"
            f"{'' if r['size_error'] is None else ' %'} | "
            f"{r['error_name']}: {_f(r['error_before'])} -> {_f(r['error_after'])} | "
            f"{_f(r['centroid_before'])} -> {_f(r['centroid_after'])} | "
            f"{_f(r['chamfer_before'])} -> {_f(r['chamfer_after'])} | "
            f"{_f(r['stability_before'], '{:.2f}')} -> {_f(r['stability_after'], '{:.2f}')} | "
            f"{_f(r['residual_before'], '{:.1f}')} -> {_f(r['residual_after'], '{:.1f}')} |")
    found = [r for r in rows if r["expected"]]
    clean = [r for r in rows if not r["expected"]]
    lines.append("")
    lines.append(f"Effects named first: {sum(r['named_first'] for r in found)}/{len(found)}; "
                 f"fitted within 25 %: {sum(1 for r in found if r['size_error'] is not None and r['size_error'] <= 0.25)}/{len(found)}; "
                 f"clean scenes with no effect: {sum(r['named_first'] for r in clean)}/{len(clean)}.")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--root", type=Path, default=REPO / "bench" / "diagnose")
    ap.add_argument("--cases", default=",".join(c for c in CASES if c != "clean"))
    ap.add_argument("--seeds", type=int, default=1, help="scenes per injected effect")
    ap.add_argument("--clean", type=int, default=2, help="clean scenes")
    ap.add_argument("--count", type=int, default=5, help="objects per scene")
    ap.add_argument("--stages", default="init,graph,geomopt,export,evaluate",
                    help="pipeline stages run before diagnose")
    ap.add_argument("--oracle", action="store_true",
                    help="also run the COM and friction cases on the true geometry")
    ap.add_argument("--table-only", action="store_true", help="only rebuild the table")
    ap.add_argument("--out", type=Path, default=None, help="markdown file to update")
    args = ap.parse_args()

    jobs = [("clean", s, False) for s in range(args.clean)]
    jobs += [(c, s, False) for c in args.cases.split(",") if c for s in range(args.seeds)]
    if args.oracle:
        jobs += [(c, s, True) for c in args.cases.split(",") if c in ORACLE_CASES
                 for s in range(args.seeds)]
    rows = []
    for case, seed, oracle in jobs:
        scene = args.root / f"{case}_s{seed}"
        result = scene / ("bench_diagnose_oracle.json" if oracle else "bench_diagnose.json")
        if not args.table_only:
            t0 = time.perf_counter()
            scene = make_scene(args.root, case, seed, args.count)
            if oracle:
                import shutil

                twin = args.root / f"{case}_s{seed}_oracle"
                if not twin.is_dir():
                    shutil.copytree(scene, twin,
                                    ignore=shutil.ignore_patterns("diagnose", "physopt"))
                # physopt would tune the reconstructed shapes the true geometry replaces
                run_pipeline(twin, [s for s in args.stages.split(",") if s != "physopt"])
                oracle_geometry(twin)
                scene = twin
                result = twin / "bench_diagnose.json"
            else:
                run_pipeline(scene, args.stages.split(","))
            diagnose = get_stage("diagnose")
            run_stage(diagnose, scene, build_options(diagnose, None, {}), force=True)
            r = row(scene, case, seed, time.perf_counter() - t0)
            r["oracle"] = oracle
            if case == "com_offset":
                r["observable"] = com_offset_observable(scene)
            result.write_text(json.dumps(r, indent=1))
            print(f"{scene.name}: {r['decision']} fitted {r['fitted']} "
                  f"({r['error_name']} {r['error_before']} -> {r['error_after']}) "
                  f"{r['seconds']:.0f} s", flush=True)
        if args.table_only and oracle:
            result = args.root / f"{case}_s{seed}_oracle" / "bench_diagnose.json"
        if result.is_file():
            rows.append(json.loads(result.read_text()))
    text = table(rows)
    print(text)
    if args.out:
        write_generated_block(args.out, "bench_diagnose", text)


if __name__ == "__main__":
    main()
