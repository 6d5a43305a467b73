"""Atomic writes: a file or a whole stage folder appears complete or not at all.

A stage writes into ``<scene>/.tmp-<name>-<pid>/`` and :func:`commit_dir` swaps it into
place; an interrupted stage leaves the previous result untouched, and
:func:`recover_dir` (called before every stage) undoes a swap that was cut in half.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"cannot serialise {type(obj).__name__} to JSON")


def dumps_json(data: Any) -> str:
    """JSON text with numpy support, NaN written as null."""
    return json.dumps(_nan_to_none(data), indent=1, default=_json_default, allow_nan=False)


def _nan_to_none(obj: Any) -> Any:
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    if isinstance(obj, np.floating) and not np.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _nan_to_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_nan_to_none(v) for v in obj]
    if isinstance(obj, np.ndarray) and obj.dtype.kind == "f":
        return _nan_to_none(obj.tolist())
    return obj


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same folder and a rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.chmod(tmp, 0o644)  # mkstemp makes 0600 files; outputs are ordinary files
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_json(path: Path, data: Any) -> None:
    """Write ``data`` as indented JSON, atomically."""
    atomic_write_bytes(Path(path), dumps_json(data).encode())


def atomic_write_text(path: Path, text: str) -> None:
    atomic_write_bytes(Path(path), text.encode())


def scratch_dir(final: Path) -> Path:
    """A fresh, empty sibling folder of ``final`` to write a stage's outputs into."""
    final = Path(final)
    tmp = final.parent / f".tmp-{final.name}-{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    return tmp


def _old_path(final: Path) -> Path:
    return final.parent / f".old-{final.name}"


def recover_dir(final: Path) -> None:
    """Undo a half-done :func:`commit_dir` and drop stale scratch folders of ``final``."""
    final = Path(final)
    old = _old_path(final)
    if old.exists():
        if final.exists():
            shutil.rmtree(old)
        else:
            os.replace(old, final)
    for stale in final.parent.glob(f".tmp-{final.name}-*"):
        shutil.rmtree(stale, ignore_errors=True)


def commit_dir(tmp: Path, final: Path) -> None:
    """Swap the finished scratch folder ``tmp`` into ``final`` (two renames)."""
    tmp, final = Path(tmp), Path(final)
    old = _old_path(final)
    if old.exists():
        shutil.rmtree(old)
    if final.exists():
        os.replace(final, old)
    os.replace(tmp, final)
    if old.exists():
        shutil.rmtree(old)


def recover_scene(root: Path) -> list[str]:
    """Undo half-done swaps and drop every stage's scratch folder under ``root``.

    Call only while holding the scene's lock (:mod:`r2s.io.scene_lock`): then no scratch
    folder belongs to a live run. Returns the names of the folders removed or restored.
    """
    root = Path(root)
    touched: list[str] = []
    for entry in sorted(root.iterdir()):
        name = entry.name
        if not entry.is_dir():
            continue
        if name.startswith(".old-"):
            recover_dir(root / name[len(".old-"):])
            touched.append(name)
        elif name.startswith(".tmp-"):
            shutil.rmtree(entry, ignore_errors=True)
            touched.append(name)
    return touched
