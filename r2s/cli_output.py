"""What the CLI prints after a stage or a pipeline run: the tables, the JSON document of
``--json``, and the closing line saying where the results are.

The runner returns :class:`r2s.runner.base.StageResult` objects and prints nothing; this
module turns them into output (rich only through :mod:`r2s.console`).
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
from pathlib import Path
from typing import Any, Iterator, Sequence

from r2s.io.paths import ScenePaths

PICTURE_SUFFIXES = (".png", ".jpg", ".svg")


@contextlib.contextmanager
def no_progress(name: str) -> Iterator[Any]:  # noqa: ARG001
    """A progress factory that shows nothing (``--json``)."""
    yield lambda message, fraction: None


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def print_results(results: Sequence[Any], already_said: Sequence[str] = ()) -> None:
    """The stage table, the stages' flags and warnings (those not in ``already_said``),
    then the evaluation table when evaluate is among ``results``."""
    from r2s.console import print_table

    from r2s.console import print_warning

    rows = []
    for r in results:
        status = "[green]ran[/green]" if r.ran else f"[dim]{r.reason}[/dim]"
        brief = ", ".join(f"{k}={_fmt(v)}" for k, v in list(r.summary.items())[:4]
                          if k not in ("flags", "warnings"))
        rows.append([r.name, status, f"{r.seconds:.1f}", brief])
    print_table("stages", ["stage", "status", "seconds", "summary"], rows)
    said = set(already_said)
    for r in results:  # probably-wrong results: one line each, also in the stage summary
        lines = [f if f.startswith("/") else f"{r.name}: {f}" for f in r.summary.get("flags") or []]
        lines += [f"{r.name}: {w}" for w in r.summary.get("warnings") or []]
        for line in lines:
            if line not in said:  # a stage's flags may repeat input/'s warnings
                said.add(line)
                print_warning(line)
    for r in results:
        if r.name == "evaluate" and r.summary:
            metric_rows = [[k, _fmt(v)] for k, v in r.summary.items()
                           if not isinstance(v, (list, dict))]
            print_table("evaluation", ["metric", "value"], metric_rows)


def pictures(scene_dir: Path) -> list[Path]:
    """Picture files written by the stages (``<stage>/*.png`` ...), sorted."""
    paths = ScenePaths(Path(scene_dir))
    found: list[Path] = []
    for child in sorted(paths.root.iterdir()) if paths.root.is_dir() else []:
        if not child.is_dir() or child.name in ("input", "gt", "export") \
                or child.name.startswith("."):
            continue
        found += sorted(p for p in child.rglob("*") if p.suffix.lower() in PICTURE_SUFFIXES)
    return found


def where_line(scene_dir: Path) -> str:
    """``export: <dir>; pictures: <dirs>`` for the closing line (paths as given)."""
    scene = Path(scene_dir)
    parts = []
    export = ScenePaths(scene).export
    if export.is_dir():
        parts.append(f"export: {scene / export.name}/")
    folders = sorted({p.parent.relative_to(scene.resolve()) if p.is_absolute() else p.parent
                      for p in (q.resolve() for q in pictures(scene))})
    if folders:
        parts.append("pictures: " + ", ".join(f"{scene / f}/" for f in folders))
    return "; ".join(parts) if parts else f"results in {scene}/"


def print_where(scene_dir: Path) -> None:
    """The closing line (stderr is kept for errors; this goes with the tables on stdout)."""
    from r2s.console import console

    console.print(where_line(scene_dir), soft_wrap=True, highlight=False, markup=False)


def results_document(scene_dir: Path, results: Sequence[Any]) -> dict:
    """The ``--json`` document: one entry per stage, the metrics, where the results are."""
    scene = Path(scene_dir)
    paths = ScenePaths(scene)
    metrics = None
    if paths.metrics.is_file():
        metrics = json.loads(paths.metrics.read_text())
    return {
        "scene": str(scene),
        "stages": [{"name": r.name, "ran": r.ran, "reason": r.reason,
                    "seconds": round(float(r.seconds), 3), "summary": r.summary}
                   for r in results],
        "metrics": metrics,
        "export": str(scene / paths.export.name) if paths.export.is_dir() else None,
        "pictures": [str(scene / p.resolve().relative_to(scene.resolve()))
                     for p in pictures(scene)],
    }


@contextlib.contextmanager
def stdout_reserved_for_json() -> Iterator[Any]:
    """While inside, anything written to stdout (Python's or C libraries' file descriptor 1,
    e.g. PyBullet's banner) goes to stderr; yields a writer to the real stdout."""
    sys.stdout.flush()
    saved = os.dup(1)
    os.dup2(2, 1)
    real = os.fdopen(saved, "w", closefd=True)
    try:
        yield real
    finally:
        sys.stdout.flush()
        real.flush()
        os.dup2(real.fileno(), 1)
        real.close()


def emit_json(out: Any, document: dict) -> None:
    out.write(json.dumps(document, indent=2, default=_json_default) + "\n")
    out.flush()


def _json_default(value: Any) -> Any:
    if isinstance(value, Path):
        return str(value)
    try:
        import numpy as np

        if isinstance(value, np.generic):
            return value.item()
        if isinstance(value, np.ndarray):
            return value.tolist()
    except ImportError:  # pragma: no cover
        pass
    return str(value)
