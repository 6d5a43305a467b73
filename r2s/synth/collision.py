"""Collision geometry of a ground-truth body: exactly what ``r2s export`` will build from it.

The export stage loads ``gt/meshes/<id>.glb``, welds it (:func:`r2s.io.mesh_io.welded`)
and calls :func:`r2s.geometry.convex_cache.cached_convex_decomposition` with the defaults
of its options (:data:`r2s.geometry.convex_params.DEFAULT_CONVEX`, the one home of those
parameters, so the two cannot drift apart); the generator settles and verifies the scene with the very same pieces, so that
exporting the ground truth reproduces the verified rest state. It also primes the scene's
``.cache/convex`` memo, so that ``r2s export --set source=gt`` reuses those pieces.

A decomposition can take a while (seconds to minutes for a hollow object), so pieces are
also memoised per user in ``$R2S_CACHE_DIR/convex/<code>`` (default ``~/.cache/r2s``),
where ``<code>`` fingerprints the decomposition code and parameters: a change to either
starts a fresh memo.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import os
import shutil
from functools import lru_cache
from pathlib import Path
from typing import Optional

import trimesh

from r2s.geometry import convex, convex_cache
from r2s.geometry.convex_cache import cached_convex_decomposition, mesh_key
from r2s.geometry.convex_params import DEFAULT_CONVEX
from r2s.io.mesh_io import welded


@lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """Short hash of the decomposition code and the export's parameters."""
    h = hashlib.sha256()
    for module in (convex, convex_cache):
        h.update(inspect.getsource(module).encode())
    h.update(json.dumps(DEFAULT_CONVEX.as_kwargs(), sort_keys=True).encode())
    return h.hexdigest()[:12]


def default_cache_dir() -> Optional[Path]:
    """``$R2S_CACHE_DIR/convex/<code>`` or ``~/.cache/r2s/convex/<code>``; None if it cannot
    be created."""
    root = os.environ.get("R2S_CACHE_DIR")
    base = Path(root) if root else Path.home() / ".cache" / "r2s"
    folder = base / "convex" / code_fingerprint()
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    return folder if os.access(folder, os.W_OK) else None


def piece_key(mesh: trimesh.Trimesh) -> str:
    """The memo file stem of ``mesh`` (the export's key: the defaults of
    :func:`cached_convex_decomposition` plus the export's parameters)."""
    return mesh_key(welded(mesh), **DEFAULT_CONVEX.as_kwargs(), seed=0)


def collision_pieces(mesh: trimesh.Trimesh, cache_dir: Optional[Path]) -> list[trimesh.Trimesh]:
    """Convex pieces (object frame) of a body mesh, as ``r2s export`` computes them.

    Parameters
    ----------
    mesh : closed body mesh with float32-exact vertices (what its GLB file holds).
    cache_dir : folder of the memo, or None to always decompose.
    """
    return cached_convex_decomposition(welded(mesh), cache_dir, **DEFAULT_CONVEX.as_kwargs())


def prime_scene_cache(mesh: trimesh.Trimesh, cache_dir: Optional[Path], scene_cache: Path
                      ) -> None:
    """Put the pieces of ``mesh`` into a scene's ``.cache/convex`` under the export's key."""
    src = Path(cache_dir) / f"{piece_key(mesh)}.npz" if cache_dir is not None else None
    if src is not None and src.is_file():
        scene_cache.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, scene_cache / src.name)
    else:
        collision_pieces(mesh, scene_cache)
