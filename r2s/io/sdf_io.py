"""SDF volumes on disk: ``<dir>/<id>.npy`` (R, R, R) float32 plus a ``<id>.json`` sidecar.

The sidecar says how to read the array::

    {"format": "r2s-sdf", "version": 1, "resolution": 128,
     "origin_m": [x, y, z],          # object-frame centre of voxel [0, 0, 0]
     "voxel_size_m": 0.0012,
     "index_order": "ijk=xyz",       # values[i, j, k] is at origin + voxel * (i, j, k)
     "sign": "negative_inside", "frame": "object",
     "mesh_sha256": "...", ...}      # extra keys: what the grid was computed from

A voxel's world position is ``world_from_object @ (origin_m + voxel_size_m * ijk)``.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any, Optional

import numpy as np

from r2s.errors import InputError
from r2s.geometry.sdf import FRAME, SIGN_CONVENTION, SdfGrid
from r2s.io.atomic import atomic_write_bytes, atomic_write_json
from r2s.io.input_scene import read_json_file

SDF_FORMAT = "r2s-sdf"
SDF_VERSION = 1


def sdf_paths(folder: Path, name: str | int) -> tuple[Path, Path]:
    """(array path, sidecar path) of SDF ``name`` in ``folder``."""
    folder = Path(folder)
    return folder / f"{name}.npy", folder / f"{name}.json"


def save_sdf(grid: SdfGrid, folder: Path, name: str | int,
             extra: Optional[dict[str, Any]] = None) -> None:
    """Write ``<folder>/<name>.npy`` and ``<name>.json`` atomically (array first)."""
    npy, side = sdf_paths(folder, name)
    buf = io.BytesIO()
    np.save(buf, grid.values_m.astype(np.float32), allow_pickle=False)
    atomic_write_bytes(npy, buf.getvalue())
    meta = {
        "format": SDF_FORMAT, "version": SDF_VERSION,
        "resolution": grid.resolution,
        "origin_m": [float(v) for v in grid.origin_m],
        "voxel_size_m": grid.voxel_size_m,
        "index_order": "ijk=xyz",
        "sign": grid.sign, "frame": grid.frame,
    }
    meta.update(extra or {})
    atomic_write_json(side, meta)


def read_sdf_meta(folder: Path, name: str | int) -> dict[str, Any]:
    """The sidecar of SDF ``name`` as a dict (:class:`InputError` if missing or bad)."""
    _, side = sdf_paths(folder, name)
    meta = read_json_file(side)
    if not isinstance(meta, dict) or meta.get("format") != SDF_FORMAT:
        raise InputError(side, f"not an {SDF_FORMAT} sidecar")
    return meta


def load_sdf(folder: Path, name: str | int) -> SdfGrid:
    """Read an SDF written by :func:`save_sdf`; :class:`InputError` on any mismatch."""
    npy, side = sdf_paths(folder, name)
    meta = read_sdf_meta(folder, name)
    if meta.get("sign") != SIGN_CONVENTION or meta.get("frame") != FRAME:
        raise InputError(side, f"unsupported sign/frame {meta.get('sign')}/{meta.get('frame')}")
    if meta.get("index_order") != "ijk=xyz":
        raise InputError(side, f"unsupported index order {meta.get('index_order')}")
    if not npy.is_file():
        raise InputError(npy, "missing SDF array")
    try:
        values = np.load(npy, allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise InputError(npy, f"unreadable SDF array ({exc})") from None
    r = int(meta.get("resolution", -1))
    if values.shape != (r, r, r):
        raise InputError(npy, f"shape {values.shape} does not match resolution {r}")
    try:
        return SdfGrid(values_m=values, origin_m=np.asarray(meta["origin_m"], dtype=float),
                       voxel_size_m=float(meta["voxel_size_m"]))
    except (KeyError, ValueError) as exc:
        raise InputError(side, f"bad SDF sidecar ({exc})") from None
