"""CPU seconds of each stage of ``r2s run``, this tree against an older one, and whether
the two produce the same files.

CPU time (``time.process_time``: user + system of the process, all threads) is far less
sensitive than wall time to the other jobs of a shared machine. For each scene, the two
source trees run alternately (old, new, old, new, ...) on fresh copies of the scene's
input, each in a fresh process, so both see the same load. Every file of the finished
scenes is then compared byte for byte except ``manifest.json`` (it records run times)
and ``.cache/``. Prints a markdown table (medians) and the comparison.

    git archive <old-commit> | tar -x -C /tmp/r2s_old
    python scripts/bench_stage_cpu.py --old /tmp/r2s_old --repeats 2 SCENE [SCENE ...]
    python scripts/bench_stage_cpu.py --child SRC SCENE OUT.json   # one timed run
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
STAGES = ("init", "graph", "geomopt", "physopt", "texture", "export", "evaluate")


def child(src: Path, scene: Path, out: Path) -> None:
    """One ``r2s run`` of ``scene`` with the r2s of ``src``; CPU seconds into ``out``."""
    sys.path.insert(0, str(src))
    c0 = time.process_time()
    import r2s.runner.base as base
    import r2s.runner.pipeline as pipeline
    from r2s.runner.registry import get_stage

    assert Path(pipeline.__file__).resolve().is_relative_to(src.resolve()), pipeline.__file__
    for name in STAGES:
        get_stage(name)
    cpu = {"imports": time.process_time() - c0}
    inner = base._run_stage_locked

    def timed(spec, *args, **kwargs):
        t = time.process_time()
        try:
            return inner(spec, *args, **kwargs)
        finally:
            cpu[spec.name] = cpu.get(spec.name, 0.0) + time.process_time() - t

    base._run_stage_locked = timed
    pipeline.run_pipeline(scene)
    cpu["total"] = time.process_time()
    out.write_text(json.dumps(cpu, indent=1))


def scene_files(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and p.name != "manifest.json"
            and not p.relative_to(root).as_posix().startswith(".cache")}


def differing(a: Path, b: Path) -> list[str]:
    fa, fb = scene_files(a), scene_files(b)
    return sorted(set(fa) ^ set(fb)) + sorted(k for k in set(fa) & set(fb) if fa[k] != fb[k])


def timed_run(src: Path, scene: Path, work: Path, tag: str) -> tuple[dict, Path]:
    run_dir = work / tag
    shutil.rmtree(run_dir, ignore_errors=True)
    run_dir.mkdir(parents=True)
    for part in ("input", "gt"):
        if (scene / part).exists():
            shutil.copytree(scene / part, run_dir / part)
    out = work / f"{tag}.cpu.json"
    subprocess.run([sys.executable, __file__, "--child", str(src), str(run_dir), str(out)],
                   cwd=src, check=True, capture_output=True)
    return json.loads(out.read_text()), run_dir


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--child", nargs=3, type=Path, metavar=("SRC", "SCENE", "OUT"))
    ap.add_argument("--old", type=Path, help="Source tree of the older r2s.")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--work", type=Path, default=REPO / "build" / "bench_stage_cpu")
    ap.add_argument("scenes", nargs="*", type=Path, help="Scenes (input/ and gt/ are used).")
    args = ap.parse_args()
    if args.child:
        child(*args.child)
        return
    if args.old is None or not args.scenes:
        ap.error("--old and at least one scene are needed")
    # the children run in the source trees: every path absolute
    args.old, args.work = args.old.resolve(), args.work.resolve()
    args.scenes = [s.resolve() for s in args.scenes]
    for scene in args.scenes:
        runs: dict[str, list[dict]] = {"old": [], "new": []}
        dirs: dict[str, list[Path]] = {"old": [], "new": []}
        for k in range(args.repeats):
            for which, src in (("old", args.old), ("new", REPO)):
                cpu, run_dir = timed_run(src, scene, args.work / scene.name, f"{which}{k}")
                runs[which].append(cpu)
                dirs[which].append(run_dir)
        print(f"\n{scene.name}: CPU seconds, median of {args.repeats}\n")
        print("| part | old | new | new / old |\n|---|---|---|---|")
        for key in ("imports", *STAGES, "total"):
            old = statistics.median(r.get(key, 0.0) for r in runs["old"])
            new = statistics.median(r.get(key, 0.0) for r in runs["new"])
            print(f"| {key} | {old:.2f} | {new:.2f} | {new / old if old else float('nan'):.2f} |")
        for k in range(args.repeats):
            diff = differing(dirs["old"][k], dirs["new"][k])
            print(f"\nrun {k}: {len(scene_files(dirs['new'][k]))} files, "
                  f"{len(diff)} differ between old and new: {diff}")
        same = differing(dirs["old"][0], dirs["old"][-1]) if args.repeats > 1 else []
        print(f"old against itself (run 0 and {args.repeats - 1}): {same}")


if __name__ == "__main__":
    main()
