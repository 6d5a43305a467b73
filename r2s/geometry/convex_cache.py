"""A content-addressed on-disk cache for convex decompositions (CoACD takes seconds a mesh).

Key: sha256 of the mesh's vertices and faces and the decomposition parameters. The cache
lives in ``<scene>/.cache/convex/`` and is safe to delete.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import trimesh

from r2s.geometry.convex import convex_decomposition
from r2s.io.atomic import atomic_write_bytes


def mesh_key(mesh: trimesh.Trimesh, **params: object) -> str:
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(mesh.vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes())
    h.update(json.dumps(params, sort_keys=True).encode())
    return h.hexdigest()[:32]


def cached_convex_decomposition(mesh: trimesh.Trimesh, cache_dir: Path | None,
                                threshold: float = 0.05, max_pieces: int = 64,
                                seed: int = 0, method: str = "vhacd") -> list[trimesh.Trimesh]:
    """:func:`r2s.geometry.convex.convex_decomposition`, memoised in ``cache_dir`` (the key
    names ``method`` only when it is not V-HACD, the default)."""
    if cache_dir is None:
        return convex_decomposition(mesh, threshold=threshold, max_pieces=max_pieces, seed=seed,
                                    method=method)
    extra = {} if method == "vhacd" else {"method": method}
    key = mesh_key(mesh, threshold=threshold, max_pieces=max_pieces, seed=seed, **extra)
    path = Path(cache_dir) / f"{key}.npz"
    if path.is_file():
        try:
            data = np.load(path)
            count = int(data["count"])
            return [trimesh.Trimesh(data[f"v{k}"], data[f"f{k}"], process=False)
                    for k in range(count)]
        except Exception:
            path.unlink(missing_ok=True)
    pieces = convex_decomposition(mesh, threshold=threshold, max_pieces=max_pieces, seed=seed,
                                  method=method)
    arrays: dict[str, np.ndarray] = {"count": np.array(len(pieces))}
    for k, p in enumerate(pieces):
        arrays[f"v{k}"] = np.asarray(p.vertices)
        arrays[f"f{k}"] = np.asarray(p.faces)
    import io

    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_write_bytes(path, buf.getvalue())
    return pieces
