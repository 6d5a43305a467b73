"""Where the time of ``r2s`` goes: start-up, each stage, the PyBullet checks inside physopt,
SDF building, and a no-op ``r2s run`` (with the shortcut and with the full hash check).

Every figure is the median of ``--repeats`` runs, each in a fresh process (so imports are
paid as a user pays them). Scenes are synthesised once into ``--work`` (``r2s synth``) and
copied input-only for every pipeline run. Writes the table into docs/speed.md.

    python scripts/bench_speed.py --objects 6,14 --repeats 3
    python scripts/bench_speed.py --child SCENE      # one timed run (used by the above)
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts"))
sys.path.insert(0, str(REPO))  # the child measures this tree's r2s, not an installed one

from doc_block import write_generated_block  # noqa: E402

STAGES = ("init", "graph", "geomopt", "physopt", "texture", "export", "evaluate")


def child(scene: Path) -> dict:
    """One full ``r2s run`` in this process with timers around the parts of interest."""
    t0, c0 = time.perf_counter(), time.process_time()
    import r2s.runner.base as base
    import r2s.runner.pipeline as pipeline
    from r2s.runner.registry import get_stage

    for name in STAGES:
        get_stage(name)
    imports_s, imports_cpu_s = time.perf_counter() - t0, time.process_time() - c0
    timers = {"sdf_s": 0.0, "physopt_pybullet_s": 0.0, "sdf_cpu_s": 0.0,
              "physopt_pybullet_cpu_s": 0.0}
    cpu: dict[str, float] = {}
    inner = base._run_stage_locked

    def cpu_timed(spec, *a, **k):
        c = time.process_time()
        try:
            return inner(spec, *a, **k)
        finally:
            cpu[f"{spec.name}_cpu_s"] = cpu.get(f"{spec.name}_cpu_s", 0.0) \
                + time.process_time() - c

    base._run_stage_locked = cpu_timed

    def timed(module, attr: str, key: str) -> None:
        fn = getattr(module, attr)

        def wrapper(*a, **k):
            s, c = time.perf_counter(), time.process_time()
            try:
                return fn(*a, **k)
            finally:
                timers[key] += time.perf_counter() - s
                timers[key.replace("_s", "_cpu_s")] += time.process_time() - c

        setattr(module, attr, wrapper)

    import r2s.physopt.object_opt as object_opt
    import r2s.physopt.solve as physopt_solve
    import r2s.sim.diffsim.obstacles as obstacles
    import r2s.stages.geomopt as geomopt_stage

    for module in (geomopt_stage, object_opt, obstacles):
        timed(module, "compute_sdf", "sdf_s")
    for attr in ("depenetrate_scene", "verify_and_repair"):
        timed(physopt_solve, attr, "physopt_pybullet_s")
    t1 = time.perf_counter()
    results = pipeline.run_pipeline(scene)
    run_s = time.perf_counter() - t1
    return {"imports_s": imports_s, "imports_cpu_s": imports_cpu_s, "run_s": run_s,
            "total_s": time.perf_counter() - t0, **timers, **cpu,
            **{f"{r.name}_s": r.seconds for r in results}}


CPU_S: dict[str, list[float]] = {}
"""CPU seconds (user + system) of the child of each timed command, by label: less sensitive
than wall time to other jobs on a shared machine."""


def timed_command(cmd: list[str], cwd: Path = REPO, label: str = "") -> float:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, cwd=cwd, check=True, capture_output=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if label:
        CPU_S.setdefault(label, []).append(after.ru_utime - before.ru_utime
                                           + after.ru_stime - before.ru_stime)
    return wall


def startup_rows(py: str, repeats: int) -> list[tuple[str, str]]:
    startup = [timed_command([py, "-c", "import r2s"], label="import") for _ in range(repeats)]
    helps = [timed_command([py, "-m", "r2s.cli", "--help"], label="help")
             for _ in range(repeats)]
    return [("`python -c 'import r2s'`",
             f"{median(startup):.2f} s (CPU {median(CPU_S['import']):.2f} s)"),
            ("`r2s --help`", f"{median(helps):.2f} s (CPU {median(CPU_S['help']):.2f} s)")]


def noop_rows(py: str, scene: Path, label: str, repeats: int) -> list[tuple[str, str]]:
    """No-op ``r2s run`` on a finished scene: the shortcut, then the full check (the record
    removed before each), alternating so both see the same load."""
    quick, full = [], []
    for _ in range(repeats):
        timed_command([py, "-m", "r2s.cli", "run", str(scene)])  # (re)writes the record
        quick.append(timed_command([py, "-m", "r2s.cli", "run", str(scene)], label="quick"))
        (scene / ".cache" / "up_to_date.json").unlink(missing_ok=True)
        full.append(timed_command([py, "-m", "r2s.cli", "run", str(scene)], label="full"))
    return [(f"{label}: no-op `r2s run` (shortcut)",
             f"{median(quick):.2f} s (CPU {median(CPU_S['quick']):.2f} s)"),
            (f"{label}: no-op `r2s run` (full hash check, all stages imported)",
             f"{median(full):.2f} s (CPU {median(CPU_S['full']):.2f} s)"),
            (f"{label}: no-op shortcut / full check",
             f"{median(quick) / median(full):.2f}x wall, "
             f"{median(CPU_S['quick']) / median(CPU_S['full']):.2f}x CPU")]


def input_copy(src: Path, dst: Path) -> Path:
    if dst.exists():
        shutil.rmtree(dst)
    dst.mkdir(parents=True)
    for part in ("input", "gt"):
        if (src / part).exists():
            shutil.copytree(src / part, dst / part)
    if (src / ".cache" / "convex").is_dir():  # synth's primed pieces, as a user has them
        shutil.copytree(src / ".cache" / "convex", dst / ".cache" / "convex")
    return dst


def median(values: list[float]) -> float:
    return statistics.median(values) if values else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--objects", default="6,14", help="Object counts of the synthetic scenes.")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--work", type=Path, default=REPO / "build" / "bench_speed")
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--note", default="", help="Said under the table (e.g. a shared machine).")
    ap.add_argument("--out", type=Path, default=REPO / "docs" / "speed.md")
    ap.add_argument("--noop-only", type=Path, metavar="SCENE",
                    help="Only start-up and the no-op run on this finished scene (own table).")
    args = ap.parse_args()
    py = sys.executable
    env_py = [py, "-m", "r2s.cli"]
    if args.child is not None:
        print(json.dumps(child(args.child)))
        return

    if args.noop_only is not None:
        rows = startup_rows(py, args.repeats) + noop_rows(py, args.noop_only, "finished scene",
                                                          args.repeats)
        write_table(args, rows, "speed-noop")
        return
    rows = startup_rows(py, args.repeats)
    for count in [int(c) for c in args.objects.split(",")]:
        source = args.work / f"synth{count}"
        if not (source / "input").is_dir():
            subprocess.run(env_py + ["synth", str(source), "--count", str(count), "--seed", "0",
                                     "--width", str(args.width), "--height", str(args.height)],
                           cwd=REPO, check=True, capture_output=True)
        n_obj = len(json.loads((source / "gt" / "scene.json").read_text())["objects"])
        runs = []
        for k in range(args.repeats):
            scene = input_copy(source, args.work / f"run{count}_{k}")
            t0 = time.perf_counter()
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            out = subprocess.run([py, __file__, "--child", str(scene)], cwd=REPO, check=True,
                                 capture_output=True, text=True)
            wall = time.perf_counter() - t0
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            runs.append({**json.loads(out.stdout.strip().splitlines()[-1]), "wall_s": wall,
                         "cpu_s": after.ru_utime - before.ru_utime
                         + after.ru_stime - before.ru_stime})
        last = args.work / f"run{count}_{args.repeats - 1}"
        label = f"{n_obj} objects"

        def both(key: str) -> str:
            return (f"{median([r[f'{key}_s'] for r in runs]):.2f} s "
                    f"(CPU {median([r.get(f'{key}_cpu_s', float('nan')) for r in runs]):.2f} s)")

        rows.append((f"**{label}: `r2s run` end to end** (process wall, CPU of the process)",
                     f"**{median([r['wall_s'] for r in runs]):.1f} s (CPU "
                     f"{median([r['cpu_s'] for r in runs]):.1f} s)**"))
        rows.append((f"{label}: imports of all stages", both("imports")))
        for name in STAGES:
            rows.append((f"{label}: {name}", both(name)))
        rows.append((f"{label}: physopt's PyBullet checks (depenetrate + verify/repair)",
                     both("physopt_pybullet")))
        rows.append((f"{label}: SDF building (geomopt + physopt)",
                     both("sdf")))
        rows += noop_rows(py, last, label, args.repeats)
    write_table(args, rows, "speed")


def write_table(args: argparse.Namespace, rows: list[tuple[str, str]], block: str) -> None:
    table = "| what | median of %d |\n|---|---|\n" % args.repeats
    table += "".join(f"| {a} | {b} |\n" for a, b in rows)
    if args.note:
        table += f"\n{args.note}\n"
    cpu = os.cpu_count()
    table += f"\nMachine: {cpu} CPU cores; Python {sys.version.split()[0]}.\n"
    write_generated_block(args.out, block, table)
    print(table)


if __name__ == "__main__":
    main()
