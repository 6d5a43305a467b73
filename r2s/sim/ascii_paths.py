"""Hand PyBullet only ASCII file names.

PyBullet's mesh loaders crash the process (SIGSEGV, in ``createCollisionShapeArray``) when a
file name holds non-ASCII characters. :func:`ascii_safe_paths` gives, for the ``with``
block, a name PyBullet can read for each file: the path itself when it is ASCII, otherwise
a symbolic link (a copy where links are not allowed) in a fresh temporary folder whose
name is ASCII. PyBullet reads the files during the call that names them, so the links may
go when the block ends.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Sequence


def is_ascii_path(path: Path | str) -> bool:
    return str(path).isascii()


def _link(path: Path, slot: Path) -> str:
    """An ASCII name for ``path`` under the empty slot folder: the file's own folder linked
    (so files it names relative to itself, an .obj's .mtl, still resolve) when its base name
    is ASCII, else the file linked or copied under an ASCII name."""
    slot.mkdir()
    if path.name.isascii():
        try:
            os.symlink(path.parent, slot / "d", target_is_directory=True)
            return str(slot / "d" / path.name)
        except OSError:
            pass
    suffix = path.suffix if path.suffix.isascii() else ""
    target = slot / f"file{suffix}"
    try:
        os.symlink(path, target)
    except OSError:
        shutil.copyfile(path, target)
    return str(target)


@contextmanager
def ascii_safe_paths(files: Sequence[Path | str]) -> Iterator[list[str]]:
    """ASCII names for ``files`` (same order), valid inside the ``with`` block."""
    names = [str(f) for f in files]
    if all(is_ascii_path(n) for n in names):
        yield names
        return
    tmp = tempfile.mkdtemp(prefix="r2s-ascii-")
    if not tmp.isascii():  # TMPDIR itself has other characters
        shutil.rmtree(tmp, ignore_errors=True)
        tmp = tempfile.mkdtemp(prefix="r2s-ascii-", dir="/tmp")
    try:
        out = []
        for k, name in enumerate(names):
            if is_ascii_path(name):
                out.append(name)
                continue
            out.append(_link(Path(name).absolute(), Path(tmp) / str(k)))
        yield out
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
