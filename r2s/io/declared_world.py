"""``export/declared_world.json``: how the export's world relates to the declared one.

When the declared camera pose was corrected (a ``camera_rotation`` kept by ``r2s diagnose
--set apply=true``, or a pose that tilts the table beyond any real table, levelled by
:func:`r2s.scene_model.levelled`), the export is in the corrected world. This file, beside
``scene.json``, says so for readers whose robot lives in the world of camera.json, and for
r2s's own readers of the export that place the input camera in it (the viewer, ``predict``).

Layout (4 x 4 row-major transforms, metres)::

    {"why": "...", "corrected_from_declared": T, "declared_from_corrected": T^-1,
     "gravity_declared_world": [gx, gy, gz]}

Without a correction the file is not written.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from r2s.io.atomic import atomic_write_json
from r2s.io.input_scene import Camera, read_json_file

DECLARED_WORLD_FILE = "declared_world.json"


def write_declared_world(export_dir: Path, corrected_from_declared: np.ndarray,
                         gravity: list[float]) -> None:
    """Write the file into ``export_dir``; ``gravity`` (3,) is the export's (corrected world)."""
    t = np.asarray(corrected_from_declared, dtype=np.float64)
    declared_from_corrected = np.linalg.inv(t)
    atomic_write_json(Path(export_dir) / DECLARED_WORLD_FILE, {
        "why": "the declared camera pose was corrected (a kept camera_rotation, or a table "
               "tilted beyond any real table by the declared pose); scene.json is in the "
               "corrected world",
        "corrected_from_declared": t.tolist(),
        "declared_from_corrected": declared_from_corrected.tolist(),
        "gravity_declared_world": (declared_from_corrected[:3, :3]
                                   @ np.asarray(gravity, dtype=np.float64)).tolist()})


def corrected_from_declared(export_dir: Path) -> Optional[np.ndarray]:
    """(4, 4) from ``export_dir``'s file, or None when there is none."""
    path = Path(export_dir) / DECLARED_WORLD_FILE
    if not path.is_file():
        return None
    return np.asarray(read_json_file(path)["corrected_from_declared"], dtype=np.float64)


def camera_in_export_world(camera: Camera, export_dir: Path) -> Camera:
    """The declared ``camera`` placed in the export's world (itself without a correction)."""
    t = corrected_from_declared(export_dir)
    if t is None:
        return camera
    return Camera(K=camera.K, world_from_camera=t @ np.asarray(camera.world_from_camera),
                  width=camera.width, height=camera.height)


def points_in_export_world(points: np.ndarray, export_dir: Path) -> np.ndarray:
    """(N, 3) declared-world points (a pusher's path) in the export's world."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    t = corrected_from_declared(export_dir)
    return pts if t is None else pts @ t[:3, :3].T + t[:3, 3]
