"""Concurrent ``r2s run`` on one scene, and repeated runs: are the outputs the same?

    python scripts/check_concurrent_runs.py SCENE [--delays 0,3,10] [--repeats 3] [-- RUN ARGS]

SCENE holds input/ (and optionally gt/); every run works on a fresh copy of it. It prints

* for each delay: two ``r2s run`` started that many seconds apart on one copy, their exit
  codes and error lines, then a final ``r2s run``: its exit code and whether its export/
  (and every stage folder) is byte-identical to a single run's;
* ``--repeats`` independent full runs: whether their stage outputs (manifest.json aside)
  are byte-identical.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SKIP = {"input", "gt", ".cache"}


def outputs(scene: Path) -> dict[str, str]:
    """sha256 of every non-hidden file of every stage folder (input/, gt/ aside)."""
    out = {}
    for folder in sorted(scene.iterdir()):
        if not folder.is_dir() or folder.name in SKIP or folder.name.startswith("."):
            continue
        for f in sorted(folder.rglob("*")):
            if f.is_file() and not any(p.startswith(".") for p in f.relative_to(scene).parts):
                out[str(f.relative_to(scene))] = hashlib.sha256(f.read_bytes()).hexdigest()
    return out


def start(scene: Path, args: list[str]) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(REPO), "COLUMNS": "200"}
    return subprocess.Popen([sys.executable, "-m", "r2s.cli", "run", str(scene), *args],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)


def fresh(src: Path, parent: Path) -> Path:
    """A copy of src's input/ and gt/ under ``parent`` with src's own folder name (the
    contact graph's picture shows it in its title)."""
    dst = parent / src.resolve().name
    dst.mkdir(parents=True)
    for name in ("input", "gt"):
        if (src / name).is_dir():
            shutil.copytree(src / name, dst / name)
    return dst


def errors(text: str) -> list[str]:
    return [ln.strip() for ln in text.splitlines() if ln.strip().startswith(("error", "Traceback"))]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", type=Path)
    ap.add_argument("--delays", default="0,3,10")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("run_args", nargs="*")
    a = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="r2s-concurrent-"))
    runs = []
    for k in range(a.repeats):
        scene = fresh(a.scene, work / f"single{k}")
        t0 = time.perf_counter()
        p = start(scene, a.run_args)
        text = p.communicate()[0]
        runs.append(outputs(scene))
        print(f"single run {k}: exit {p.returncode}, {time.perf_counter() - t0:.0f} s, "
              f"{len(runs[-1])} output files {errors(text)}", flush=True)
    ref = runs[0]
    same = all(r == ref for r in runs[1:])
    print(f"{a.repeats} single runs byte-identical (manifest aside): {same}", flush=True)
    if not same:
        for k, r in enumerate(runs[1:], 1):
            print(f"  run {k} differs in", sorted(f for f in set(r) | set(ref)
                                                  if r.get(f) != ref.get(f))[:10])
    print("| delay [s] | run A exit | run B exit | B's message | final run exit | "
          "export = single run | all stage outputs = single run |")
    print("|---|---|---|---|---|---|---|")
    for delay in [float(d) for d in a.delays.split(",")]:
        scene = fresh(a.scene, work / f"delay{delay:g}")
        pa = start(scene, a.run_args)
        time.sleep(delay)
        pb = start(scene, a.run_args)
        ta, tb = pa.communicate()[0], pb.communicate()[0]
        final = start(scene, a.run_args)
        tf = final.communicate()[0]
        got = outputs(scene)
        export_same = ({k: v for k, v in got.items() if k.startswith("export/")}
                       == {k: v for k, v in ref.items() if k.startswith("export/")})
        msg = "; ".join(errors(ta) + errors(tb)) or "-"
        print(f"| {delay:g} | {pa.returncode} | {pb.returncode} | {msg} | {final.returncode}"
              f"{' ' + '; '.join(errors(tf)) if errors(tf) else ''} | {export_same} | "
              f"{got == ref} |", flush=True)
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
