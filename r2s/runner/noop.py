"""The no-op ``r2s run`` without importing any stage: a record of the last full check.

A full staleness check (:func:`r2s.runner.base.staleness`) imports every stage module (and
so torch, open3d, ...) and hashes every stage's inputs and outputs; on a finished scene it
finds nothing to do. Its answer is a function of the scene's files, the manifest, the r2s
source and the run's arguments only. So when a full check has found every stage up to date,
:func:`remember_up_to_date` writes ``.cache/up_to_date.json`` with the size and mtime of
every file of the scene (``.cache/`` and ``run.log`` aside; plus any input outside the scene
a stage hashed), of every r2s source file, and the arguments. :func:`quick_up_to_date`
answers "all up to date" only when all of these are identical; any difference (a file
touched, added or removed, another option, an edited r2s) falls back to the full check. The
comparison is make's (size + mtime), but it only ever *confirms* a hash-based answer that
was given for exactly those files.

Imports: standard library and :mod:`r2s.io.scene_lock` (the point is start-up time).
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Sequence

RECORD_NAME = "up_to_date.json"
CACHE_DIR = ".cache"  # r2s.io.paths.CACHE_DIR (not imported: it pulls in nothing, but keep
#                      this module free of r2s imports so its cost is the standard library's)
IGNORED_TOP_LEVEL = {CACHE_DIR, "run.log", ".r2s-lock"}  # r2s.io.scene_lock.LOCK_NAME
_PACKAGE = Path(__file__).resolve().parents[1]


@dataclass
class QuickResult:
    """Duck-types :class:`r2s.runner.base.StageResult` for printing and the API."""

    name: str
    ran: bool = False
    seconds: float = 0.0
    summary: dict = field(default_factory=dict)
    reason: str = "up to date"


def _file_stats(root: Path) -> dict[str, list[int]]:
    stats: dict[str, list[int]] = {}
    root_str = str(root)
    for folder, dirs, files in os.walk(root_str):
        if folder == root_str:
            dirs[:] = [d for d in dirs if d not in IGNORED_TOP_LEVEL]
            files = [f for f in files if f not in IGNORED_TOP_LEVEL]
        dirs.sort()
        for name in sorted(files):
            full = os.path.join(folder, name)
            try:
                st = os.stat(full)
            except OSError:
                continue
            stats[os.path.relpath(full, root_str)] = [st.st_size, st.st_mtime_ns]
    return stats


def _external_stats(paths: Sequence[str]) -> dict[str, list[int]]:
    out: dict[str, list[int]] = {}
    for p in paths:
        try:
            st = os.stat(p)
            out[p] = [st.st_size, st.st_mtime_ns]
        except OSError:
            out[p] = [-1, -1]
    return out


def _code_fingerprint() -> str:
    h = hashlib.sha256()
    for folder, dirs, files in os.walk(_PACKAGE):
        dirs[:] = sorted(d for d in dirs if d != "__pycache__")
        for name in sorted(files):
            if name.endswith(".py"):
                st = os.stat(os.path.join(folder, name))
                h.update(f"{folder}/{name}:{st.st_size}:{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


def arguments_key(until: Optional[str], skip: Sequence[str], overrides: dict) -> str:
    return json.dumps({"until": until, "skip": sorted(skip),
                       "overrides": {str(k): str(v) for k, v in sorted(overrides.items())}},
                      sort_keys=True)


def _state(scene: Path, external: Sequence[str], args_key: str) -> dict[str, Any]:
    return {"code": _code_fingerprint(), "arguments": args_key, "files": _file_stats(scene),
            "external": _external_stats(external)}


def remember_up_to_date(scene_dir: Path, stages: Sequence[str], external: Sequence[str],
                        args_key: str, warnings: Sequence[str]) -> None:
    """Record that a full check found ``stages`` up to date with these arguments (and the
    warnings that reading ``input/`` gave)."""
    scene = Path(scene_dir).resolve()
    record = {"stages": list(stages), "warnings": list(warnings),
              **_state(scene, external, args_key)}
    folder = scene / CACHE_DIR
    try:
        folder.mkdir(exist_ok=True)
        tmp = folder / f".{RECORD_NAME}.{os.getpid()}"
        tmp.write_text(json.dumps(record))
        os.replace(tmp, folder / RECORD_NAME)
    except OSError:  # a read-only scene: no shortcut, nothing else changes
        pass


def forget(scene_dir: Path) -> None:
    try:
        (Path(scene_dir).resolve() / CACHE_DIR / RECORD_NAME).unlink()
    except OSError:
        pass


def quick_run(scene_dir: Path, until: Optional[str], skip: Sequence[str], overrides: dict,
              wait_s: float = 0.0, notify=lambda message: None
              ) -> Optional[tuple[list[QuickResult], list[str]]]:
    """:func:`quick_up_to_date` under the scene's write lock (a scene another process is
    writing is busy, as for a full run); None for a folder without ``input/``."""
    from r2s.io.scene_lock import scene_lock  # standard library + r2s.errors

    if not (Path(scene_dir) / "input").is_dir():
        return None
    with scene_lock(Path(scene_dir), wait_s=wait_s, notify=notify):
        return quick_up_to_date(scene_dir, until, skip, overrides)


def quick_up_to_date(scene_dir: Path, until: Optional[str], skip: Sequence[str],
                     overrides: dict) -> Optional[tuple[list[QuickResult], list[str]]]:
    """The stage results of a no-op run (summaries from the manifest) and the input
    warnings, or None when the full check must run."""
    scene = Path(scene_dir).resolve()
    try:
        record = json.loads((scene / CACHE_DIR / RECORD_NAME).read_text())
    except (OSError, ValueError):
        return None
    args_key = arguments_key(until, skip, overrides)
    if record.get("arguments") != args_key:
        return None
    now = _state(scene, list(record.get("external", {})), args_key)
    if any(record.get(k) != v for k, v in now.items()):
        return None
    try:
        manifest = json.loads((scene / "manifest.json").read_text())
    except (OSError, ValueError):
        return None
    stages = manifest.get("stages", {})
    results = [QuickResult(name, summary=dict(stages.get(name, {}).get("summary") or {}))
               for name in record["stages"]]
    return results, list(record.get("warnings", []))
