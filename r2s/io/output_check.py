"""Is a stage folder whole? Declared files present, bytes as recorded.

A stage's folder declares files in its JSON: ``state.json`` names each object's ``mesh``;
``scene.json`` (export) names ``visual_mesh`` and ``collision_meshes`` (``observed_points``
stays init's, so it is not a file of later stages' folders). :func:`missing_declared` lists the declared files that do not exist;
:func:`file_hashes` gives every file's sha256 (hidden files aside, as in the manifest's
folder hash), which the manifest records per stage; :func:`changed_files` compares them
with what is on disk now.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

DECLARING_FILES: tuple[str, ...] = ("state.json", "scene.json")
"""JSON files of a stage folder whose object entries name other files of the folder."""

FILE_KEYS: tuple[str, ...] = ("mesh", "visual_mesh", "collision_meshes")
"""Keys of an object entry whose values are paths relative to the stage folder."""


def _declared(data: Any) -> list[str]:
    out: list[str] = []
    objects = data.get("objects", []) if isinstance(data, dict) else []
    for obj in objects if isinstance(objects, list) else []:
        if not isinstance(obj, dict):
            continue
        for key in FILE_KEYS:
            value = obj.get(key)
            values = value if isinstance(value, list) else [value]
            out.extend(v for v in values if isinstance(v, str) and v)
    return out


def declared_files(stage_dir: Path) -> list[str]:
    """Relative paths named by the folder's ``state.json`` / ``scene.json`` objects."""
    stage_dir = Path(stage_dir)
    names: list[str] = []
    for declaring in DECLARING_FILES:
        path = stage_dir / declaring
        if not path.is_file():
            continue
        try:
            names.extend(_declared(json.loads(path.read_text())))
        except (OSError, ValueError):
            continue  # a malformed file is the reader's to report
    return names


def missing_declared(stage_dir: Path) -> list[str]:
    """Declared files (see :func:`declared_files`) that are not files in ``stage_dir``."""
    stage_dir = Path(stage_dir)
    return [rel for rel in declared_files(stage_dir) if not (stage_dir / rel).is_file()]


def file_hashes(folder: Path) -> dict[str, str]:
    """``{relative path: sha256}`` of every non-hidden file under ``folder``."""
    folder = Path(folder)
    out: dict[str, str] = {}
    if not folder.is_dir():
        return out
    for root, dirs, files in os.walk(folder):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        for name in sorted(files):
            if name.startswith("."):
                continue
            f = Path(root) / name
            h = hashlib.sha256()
            with open(f, "rb") as fh:
                for chunk in iter(lambda: fh.read(1 << 20), b""):
                    h.update(chunk)
            out[f.relative_to(folder).as_posix()] = h.hexdigest()
    return out


def changed_files(folder: Path, recorded: dict[str, str]) -> list[str]:
    """Recorded files now missing or with other bytes, as ``"<path> missing|changed"``;
    files added since are listed as ``"<path> added"``."""
    now = file_hashes(folder)
    out = [f"{rel} missing" if rel not in now else f"{rel} changed"
           for rel, sha in sorted(recorded.items()) if now.get(rel) != sha]
    out += [f"{rel} added" for rel in sorted(set(now) - set(recorded))]
    return out


def inconsistency(folder: Path, recorded: dict[str, str] | None) -> str:
    """Why a stage folder does not match its record (first problems), or ""."""
    folder = Path(folder)
    problems = [f"{rel} missing (named in its JSON)" for rel in missing_declared(folder)]
    if recorded:
        problems += changed_files(folder, recorded)
    if not problems:
        return ""
    more = f" and {len(problems) - 2} more" if len(problems) > 2 else ""
    return ", ".join(problems[:2]) + more
