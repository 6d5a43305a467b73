#!/usr/bin/env python
"""Would a lens with a decentering term explain a scene's table? Measured, not in r2s.

For each scene after ``init``, measures the diagnose residuals (the stage's default
settings) and fits the table-shape block's flatness cost (what ``lens_distortion``
minimises) twice: over the radial k1 alone, as the catalogue's lens does, and over k1
with Brown's decentering terms p1, p2 (Nelder-Mead from the k1 fit). Prints the share of
the table's SSE each explains, the fitted terms, and whether the residual left by the
three-term lens is still structured (:func:`r2s.diagnose.stats.structure_test.test_structure`,
alpha 1e-3). A three-term lens that leaves an uncatalogued effect's table unstructured would
be named for it (docs/diagnose.md, section 10, ``lens+tangential``).

Usage:
  python scripts/lens_decentering_check.py SCENE [SCENE ...]
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.optimize import minimize, minimize_scalar

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.diagnose.data import TableShapeData  # noqa: E402
from r2s.diagnose.measure.scene_dir import measure_scene  # noqa: E402
from r2s.diagnose.stats.blocks import table_shape_block  # noqa: E402
from r2s.diagnose.stats.structure_test import test_structure  # noqa: E402
from r2s.geometry.lens import undistort_decentred  # noqa: E402
from r2s.stages.diagnose import Options, settings_of  # noqa: E402


def undistorted(shape: TableShapeData, k1: float, p1: float, p2: float) -> TableShapeData:
    """The table points back-projected through the undistorted rays (depths kept)."""
    p = shape.points_camera
    z = p[:, 2:3]
    x = undistort_decentred(p[:, :2] / z, k1, p1, p2, iterations=15)
    return replace(shape, points_camera=np.hstack([x * z, z]))


def check(scene: Path) -> str:
    res = measure_scene(scene, settings_of(Options())).residuals
    shape = res.table_shape
    sse = table_shape_block(shape).sse
    radial = minimize_scalar(lambda k: table_shape_block(undistorted(shape, k, 0, 0)).sse,
                             bounds=(-0.4, 0.4), method="bounded", options={"xatol": 1e-4})
    k1 = float(radial.x)
    full = minimize(lambda v: table_shape_block(undistorted(shape, *v)).sse, [k1, 0.0, 0.0],
                    method="Nelder-Mead",
                    options={"xatol": 1e-5, "fatol": 1e-3, "maxiter": 600,
                             "initial_simplex": [[k1, 0, 0], [k1 + 0.02, 0, 0],
                                                 [k1, 0.005, 0], [k1, 0, 0.005]]})
    left = test_structure(replace(res, table_shape=undistorted(shape, *full.x)), 1e-3)
    k, p1, p2 = full.x
    return (f"{scene.name}: table SSE {sse:.1f}; k1 alone explains "
            f"{100 * (sse - radial.fun) / sse:.1f} % (k1 {k1:+.3f}); k1, p1, p2 explain "
            f"{100 * (sse - full.fun) / sse:.1f} % (k1 {k:+.3f}, p1 {p1:+.4f}, p2 {p2:+.4f}); "
            f"left structured: {None if left is None else left.structured}")


def main() -> None:
    if len(sys.argv) < 2:
        raise SystemExit(__doc__)
    for scene in sys.argv[1:]:
        print(check(Path(scene)), flush=True)


if __name__ == "__main__":
    main()
