"""``<scene>/manifest.json``: what each stage ran with and what it produced.

Per stage: options, content hashes of the files it read and wrote, wall time, status and a
small summary. ``r2s run`` compares these hashes with the files on disk to decide what is
stale. The manifest also holds the scene's *model* (effects kept by ``diagnose --apply``),
which stages that use it list among their inputs.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Any, Optional

from pydantic import BaseModel, ConfigDict, Field

from r2s.io.atomic import atomic_write_json
from r2s.io.input_scene import read_json_file


class StageRecord(BaseModel):
    model_config = ConfigDict(extra="allow")

    status: str = "never"  # "done" | "failed" | "never"
    options: dict[str, Any] = Field(default_factory=dict)
    input_hashes: dict[str, str] = Field(default_factory=dict)
    output_hash: Optional[str] = None
    started_at: Optional[str] = None
    seconds: Optional[float] = None
    summary: dict[str, Any] = Field(default_factory=dict)
    error: Optional[str] = None
    r2s_version: Optional[str] = None


class Manifest(BaseModel):
    model_config = ConfigDict(extra="allow")

    format: str = "r2s-manifest"
    version: int = 1
    stages: dict[str, StageRecord] = Field(default_factory=dict)
    model: dict[str, Any] = Field(default_factory=dict)
    """Scene-model extensions kept by ``diagnose --apply`` (effect name -> parameters)."""


def load_manifest(path: Path) -> Manifest:
    path = Path(path)
    if not path.exists():
        return Manifest()
    try:
        return Manifest.model_validate(read_json_file(path))
    except Exception:
        # A corrupt manifest only costs a rerun: start afresh rather than refuse to work.
        return Manifest()


def save_manifest(path: Path, manifest: Manifest) -> None:
    atomic_write_json(Path(path), manifest.model_dump())


def hash_path(path: Path) -> str:
    """sha256 of a file's bytes, or of a folder's relative paths and file bytes; 'missing'."""
    path = Path(path)
    if not path.exists():
        return "missing"
    h = hashlib.sha256()
    if path.is_file():
        _hash_file(h, path)
        return h.hexdigest()
    for root, dirs, files in os.walk(path):
        dirs.sort()
        dirs[:] = [d for d in dirs if not d.startswith(".")]
        for name in sorted(files):
            if name.startswith("."):
                continue
            f = Path(root) / name
            h.update(str(f.relative_to(path)).encode())
            _hash_file(h, f)
    return h.hexdigest()


def _hash_file(h: "hashlib._Hash", path: Path) -> None:
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
