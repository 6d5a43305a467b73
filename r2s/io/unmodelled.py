"""``export/unmodelled.json``: what the camera saw on the table that the twin leaves out.

Written by export beside scene.json when init found unmasked things standing on the table
(r2s/geometry/unsegmented.py; the scene format allows files beside scene.json). A planner
can add each ``box`` as a static obstacle: it stands on the support and holds the points
the camera saw, so the real thing is at least that large (its far side may reach farther).

Layout::

    {"format": "r2s-unmodelled", "version": 1,
     "why": "...",
     "regions": [{"world_from_box": 4x4, "size_m": [x, y, z], "height_m": h,
                  "area_px": n, "box_px": [row0, col0, row1, col1],
                  "touching_ids": [...], "rests_on_it": [...]}]}

``world_from_box``: the box frame at its centre, z along the support's normal, in the
export's world (scene.json's).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from r2s.io.atomic import atomic_write_json
from r2s.io.input_scene import read_json_file

UNMODELLED_FILE = "unmodelled.json"
REGION_KEYS = ("world_from_box", "size_m", "height_m", "area_px", "box_px", "touching_ids",
               "rests_on_it")


def write_unmodelled(export_dir: Path, regions: list[dict]) -> None:
    """Write the file into ``export_dir`` from init's records of the regions."""
    atomic_write_json(Path(export_dir) / UNMODELLED_FILE, {
        "format": "r2s-unmodelled", "version": 1,
        "why": "unmasked things stand on the table (a segmenter's missed objects?); the "
               "twin leaves them out; each box holds what the camera saw of one",
        "regions": [{k: r[k] for k in REGION_KEYS if k in r} for r in regions]})


def read_unmodelled_boxes(export_dir: Path) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(world_from_box (4, 4), size_m (3,))`` of each region in ``export_dir``'s file;
    empty without the file."""
    path = Path(export_dir) / UNMODELLED_FILE
    if not path.is_file():
        return []
    return [(np.asarray(r["world_from_box"], dtype=np.float64),
             np.asarray(r["size_m"], dtype=np.float64))
            for r in (read_json_file(path) or {}).get("regions", [])]
