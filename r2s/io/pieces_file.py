"""One object's convex collision pieces as a file: physopt writes the pieces it checked,
export reads them back (``physopt/collision/<id>.npz``).

The file holds ``count``, ``v<k>`` (V, 3) float64 vertices and ``f<k>`` (F, 3) faces of
piece k (object frame, metres), and ``params``: a JSON string of the decomposition
parameters the pieces were made with (export uses the pieces only under the same ones).
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import trimesh

from r2s.io.atomic import atomic_write_bytes


def write_pieces(path: Path, pieces: list[trimesh.Trimesh], params: dict) -> None:
    """Write ``pieces`` and the ``params`` they were made with to ``path`` (atomically)."""
    arrays: dict[str, np.ndarray] = {"count": np.array(len(pieces)),
                                     "params": np.array(json.dumps(params, sort_keys=True))}
    for k, p in enumerate(pieces):
        arrays[f"v{k}"] = np.asarray(p.vertices, dtype=np.float64)
        arrays[f"f{k}"] = np.asarray(p.faces, dtype=np.int64)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_write_bytes(Path(path), buf.getvalue())


def read_pieces(path: Path, params: dict) -> list[trimesh.Trimesh] | None:
    """The pieces in ``path`` when they were made with ``params``; None when the file is
    missing, unreadable or made with other parameters."""
    try:
        with np.load(Path(path)) as data:
            if json.loads(str(data["params"])) != json.loads(json.dumps(params, sort_keys=True)):
                return None
            return [trimesh.Trimesh(data[f"v{k}"], data[f"f{k}"], process=False)
                    for k in range(int(data["count"]))]
    except (OSError, KeyError, ValueError):
        return None
