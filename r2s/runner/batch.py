"""``r2s batch ROOT``: run every scene under ROOT, then write report.md and report.csv.

- A scene is a folder holding ``input/``, found at any depth (a scene's own folders are not
  searched; hidden folders are skipped).
- Resuming is ``r2s run``'s: a stage whose inputs and options are unchanged is skipped, so a
  finished scene costs a start-up and its hashes.
- Each scene runs in a worker that caps its threads (OMP/MKL/OpenBLAS and torch) at
  ``threads`` (default: CPU cores / jobs), so ``--jobs N`` does not oversubscribe the cores.
- Executors: ``local`` runs each scene as a ``python -m r2s.runner.batch`` subprocess
  (output in ``<scene>/run.log``), ``jobs`` at a time; ``ray`` submits one task per scene to
  a Ray cluster (``RAY_ADDRESS``) or a local instance started here (scenes must be on a file
  system every node sees). The aggregate is :mod:`r2s.batch`'s, as in ``r2s report``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional, Sequence

from r2s.errors import R2SError, UsageError

THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                    "NUMEXPR_NUM_THREADS")
EXECUTORS = ("local", "ray")


@dataclass(frozen=True)
class BatchConfig:
    jobs: int = 1
    executor: str = "local"
    threads: Optional[int] = None
    """Threads per job; None: max(1, CPU cores // jobs)."""
    overrides: dict = field(default_factory=dict)
    skip: tuple[str, ...] = ()
    label: str = "r2s"

    def threads_per_job(self) -> int:
        return self.threads or max(1, (os.cpu_count() or 1) // max(self.jobs, 1))


@dataclass(frozen=True)
class SceneOutcome:
    scene: Path
    ok: bool
    seconds: float
    error: str = ""


@dataclass(frozen=True)
class BatchOutcome:
    scenes: tuple[SceneOutcome, ...]
    seconds: float
    report_md: Path
    report_csv: Path

    @property
    def failed(self) -> int:
        return sum(1 for s in self.scenes if not s.ok)


def find_scenes(root: Path) -> list[Path]:
    """Folders under ``root`` (``root`` included) that hold ``input/``, sorted."""
    root = Path(root)
    if not root.is_dir():
        raise UsageError(f"{root}: not a folder")
    found: list[Path] = []

    def walk(folder: Path) -> None:
        if (folder / "input").is_dir():
            found.append(folder)
            return
        try:
            children = sorted(p for p in folder.iterdir() if p.is_dir())
        except PermissionError:
            return
        for child in children:
            if not child.name.startswith("."):
                walk(child)

    walk(root)
    return found


def cap_threads(threads: int) -> None:
    """Cap this process's BLAS/OpenMP and torch threads (call before heavy work)."""
    for name in THREAD_VARIABLES:
        os.environ[name] = str(threads)
    if "torch" in sys.modules or _torch_available():
        import torch

        torch.set_num_threads(threads)


def _torch_available() -> bool:
    import importlib.util

    return importlib.util.find_spec("torch") is not None


def run_scene(scene: str, overrides: dict, skip: Sequence[str], threads: int) -> dict:
    """Run ``r2s run`` on one scene in this process with capped threads; never raises.
    Returns ``{"scene", "ok", "seconds", "error"}``."""
    t0 = time.perf_counter()
    from r2s.runner.noop import quick_up_to_date

    if quick_up_to_date(Path(scene), None, list(skip), dict(overrides)) is not None:
        # a finished scene: answered without importing torch (nothing to cap)
        return {"scene": scene, "ok": True, "seconds": time.perf_counter() - t0, "error": ""}
    cap_threads(threads)
    import logging

    logging.getLogger("trimesh").setLevel(logging.ERROR)
    from r2s.runner.pipeline import run_pipeline

    try:
        run_pipeline(Path(scene), skip=list(skip), overrides=dict(overrides))
        return {"scene": scene, "ok": True, "seconds": time.perf_counter() - t0, "error": ""}
    except Exception as exc:  # noqa: BLE001 - one scene's failure must not stop the batch
        kind = "" if isinstance(exc, R2SError) else f"{type(exc).__name__}: "
        return {"scene": scene, "ok": False, "seconds": time.perf_counter() - t0,
                "error": f"{kind}{exc}"}


def _worker_command(scene: Path, config: BatchConfig) -> list[str]:
    cmd = [sys.executable, "-m", "r2s.runner.batch", str(scene),
           "--threads", str(config.threads_per_job())]
    for key, value in config.overrides.items():
        cmd += ["--set", f"{key}={value}"]
    for name in config.skip:
        cmd += ["--skip", name]
    return cmd


def _run_local(scenes: list[Path], config: BatchConfig,
               progress: Callable[[str], None]) -> list[SceneOutcome]:
    env = dict(os.environ)
    for name in THREAD_VARIABLES:
        env[name] = str(config.threads_per_job())

    def one(scene: Path) -> SceneOutcome:
        t0 = time.perf_counter()
        log = scene / "run.log"
        with open(log, "w") as fh:
            proc = subprocess.run(_worker_command(scene, config), stdout=fh,
                                  stderr=subprocess.STDOUT, env=env)
        seconds = time.perf_counter() - t0
        error = ""
        if proc.returncode != 0:
            lines = [ln for ln in log.read_text(errors="replace").splitlines() if ln.strip()]
            error = lines[-1].removeprefix("error: ") if lines else f"exit {proc.returncode}"
        progress(f"{'done' if proc.returncode == 0 else 'FAILED'} {scene} ({seconds:.1f} s)")
        return SceneOutcome(scene, proc.returncode == 0, seconds, error)

    with ThreadPoolExecutor(max_workers=config.jobs) as pool:
        return list(pool.map(one, scenes))


def _run_ray(scenes: list[Path], config: BatchConfig,
             progress: Callable[[str], None]) -> list[SceneOutcome]:
    try:
        import ray
    except ImportError:
        raise R2SError("--executor ray needs ray: pip install 'r2s[ray]'") from None
    threads = config.threads_per_job()
    started_here = False
    if not ray.is_initialized():
        address = os.environ.get("RAY_ADDRESS")
        if address:
            ray.init(address=address, log_to_driver=False)
        else:  # a local instance just big enough for ``jobs`` scenes at once
            ray.init(num_cpus=config.jobs * threads, include_dashboard=False,
                     log_to_driver=False, object_store_memory=80 * 1024 * 1024)
        started_here = True
    try:
        task = ray.remote(num_cpus=threads, max_retries=0)(run_scene)
        refs = [task.remote(str(s), dict(config.overrides), list(config.skip), threads)
                for s in scenes]
        outcomes: list[SceneOutcome] = []
        for s, ref in zip(scenes, refs):
            r = ray.get(ref)
            progress(f"{'done' if r['ok'] else 'FAILED'} {s} ({r['seconds']:.1f} s)")
            outcomes.append(SceneOutcome(s, r["ok"], float(r["seconds"]), r["error"]))
        return outcomes
    finally:
        if started_here:
            ray.shutdown()


def run_batch(root: Path, config: BatchConfig, out_dir: Optional[Path] = None,
              progress: Callable[[str], None] = lambda message: None) -> BatchOutcome:
    """Run every scene under ``root`` with ``config``; write ``report.md``/``report.csv``
    into ``out_dir`` (default ``root``)."""
    from r2s.batch import write_batch_report
    from r2s.runner.pipeline import check_overrides, split_overrides
    from r2s.runner.registry import PIPELINE

    if config.executor not in EXECUTORS:
        raise UsageError(f"unknown executor '{config.executor}'; executors are "
                         f"{', '.join(EXECUTORS)}")
    if config.jobs < 1:
        raise UsageError(f"--jobs {config.jobs}: must be at least 1")
    for name in config.skip:
        if name not in PIPELINE:
            raise UsageError(f"unknown stage '{name}'; stages are {', '.join(PIPELINE)}")
    check_overrides(split_overrides(config.overrides))  # fail before any run
    scenes = find_scenes(Path(root))
    if not scenes:
        raise UsageError(f"{root}: no scene (a folder holding input/) at any depth")
    progress(f"{len(scenes)} scenes, {config.jobs} at a time, "
             f"{config.threads_per_job()} threads each ({config.executor})")
    t0 = time.perf_counter()
    run = _run_ray if config.executor == "ray" else _run_local
    outcomes = run(scenes, config, progress)
    seconds = time.perf_counter() - t0
    out = Path(out_dir) if out_dir is not None else Path(root)
    md, csv = write_batch_report(Path(root), [(o.scene, o.ok, o.seconds) for o in outcomes],
                                 out, config.label)
    return BatchOutcome(tuple(outcomes), seconds, md, csv)


def _worker_main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m r2s.runner.batch SCENE --threads N [--set k=v] [--skip stage]``: the
    local executor's worker (one scene; prints a JSON line; exit 1 when it failed)."""
    parser = argparse.ArgumentParser(prog="python -m r2s.runner.batch")
    parser.add_argument("scene")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--set", action="append", default=[])
    parser.add_argument("--skip", action="append", default=[])
    args = parser.parse_args(argv)
    overrides = dict(item.split("=", 1) for item in args.set)
    result = run_scene(args.scene, overrides, args.skip, args.threads)
    print(json.dumps(result), flush=True)
    if not result["ok"]:
        print(f"error: {result['error']}", file=sys.stderr, flush=True)
    return 0 if result["ok"] else 1


if __name__ == "__main__":
    sys.exit(_worker_main())
