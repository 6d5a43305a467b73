"""A generic residual model: is there structure left that no catalogued effect explains?

The data are the table points' distances to one plane, averaged over image tiles
(:mod:`r2s.diagnose.stats.table_shape`). Under "nothing left" each tile mean is noise of level
``sigma`` (the ``table_shape`` block's), so their sum of squares is chi-square with
``T - 3`` degrees of freedom (the plane took 3). The test rejects at ``alpha``; a rejected
residual is described by the generic feature that explains the most of it: image column,
image row, squared radius from the principal point, depth, view-ray cosine to the
surface normal (orientation), grey level (colour): a quadratic in each, its share of the
tile means' sum of squares (R^2) and the size of the pattern (the fitted curve's range
over the tiles, mm). A pattern no single feature carries, such as a depth error that grows
across the columns (the table bends by the column times the row), is described by a
quadratic in column and row together (``position``, six terms), when it explains at
least ``POSITION_MARGIN`` more than the best single feature.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np
from scipy.stats import chi2

from r2s.diagnose.data import Residuals

FEATURES = ("column", "row", "radius2", "depth", "view_cosine", "grey")
FEATURE_TEXT = {"column": "image column", "row": "image row",
                "radius2": "squared radius from the principal point", "depth": "depth",
                "view_cosine": "surface orientation (view-ray cosine)", "grey": "grey level",
                "position": "image position (column and row together)"}
POSITION_MARGIN = 0.2
"""The joint quadratic in column and row (six terms against three) describes the pattern
only when its R^2 is at least this above the best single feature's."""


@dataclass(frozen=True)
class StructureFinding:
    """Outcome of :func:`test_structure` (JSON-able through :meth:`summary`)."""

    chi2: float
    dof: int
    p_value: float
    alpha: float
    structured: bool
    amplitude_mm: float
    r2_by_feature: dict = field(default_factory=dict)
    best_feature: Optional[str] = None
    best_r2: float = 0.0
    best_range_mm: float = 0.0
    tiles_mm: tuple = ()
    centres_px: tuple = ()
    feature_values: dict = field(default_factory=dict, repr=False)
    position_fit_mm: tuple = ()
    """Per tile, the joint quadratic in column and row fitted to the residual (mm)."""

    @property
    def pattern(self) -> str:
        if self.best_feature is None:
            return "no pattern"
        return (f"table points leave their plane by up to {self.amplitude_mm:.1f} mm; "
                f"{FEATURE_TEXT[self.best_feature]} explains {100 * self.best_r2:.0f} % of it "
                f"(a quadratic in it spans {self.best_range_mm:.1f} mm)")

    def summary(self) -> dict:
        return {"chi2": self.chi2, "dof": self.dof, "p_value": self.p_value,
                "alpha": self.alpha, "structured": self.structured,
                "amplitude_mm": self.amplitude_mm, "r2_by_feature": self.r2_by_feature,
                "best_feature": self.best_feature, "best_r2": self.best_r2,
                "best_range_mm": self.best_range_mm, "pattern": self.pattern}


def _least_squares_r2(A: np.ndarray, y: np.ndarray) -> tuple[float, float, np.ndarray]:
    """(R^2 about zero, range of the fitted values, fitted values) of ``y ~ A coef``
    ((T, k) design matrix, (T,) tile means); R^2 and range 0 where ``y`` is all zero."""
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    fitted = A @ coef
    total = float(np.sum(y * y))
    if total <= 0:
        return 0.0, 0.0, fitted
    return float(1.0 - np.sum((y - fitted) ** 2) / total), float(np.ptp(fitted)), fitted


def _quadratic_r2(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(R^2 about zero, range of the fitted values) of ``y ~ a + b x + c x^2``."""
    if len(x) < 4 or np.ptp(x) < 1e-12:
        return 0.0, 0.0
    xs = (x - x.mean()) / np.std(x)
    return _least_squares_r2(np.stack([np.ones_like(xs), xs, xs * xs], axis=1), y)[:2]


def _position_fit(column: np.ndarray, row: np.ndarray, y: np.ndarray
                  ) -> tuple[float, float, np.ndarray]:
    """(R^2 about zero, range, fitted values) of ``y`` on a quadratic in column and row
    together: 1, c, r, c^2, c r, r^2 (standardised)."""
    if len(y) < 8 or np.ptp(column) < 1e-12 or np.ptp(row) < 1e-12:
        return 0.0, 0.0, np.zeros_like(y)
    c = (column - column.mean()) / np.std(column)
    r = (row - row.mean()) / np.std(row)
    return _least_squares_r2(np.stack([np.ones_like(c), c, r, c * c, c * r, r * r], axis=1), y)


def test_structure(res: Residuals, alpha: float = 1e-3) -> Optional[StructureFinding]:
    """Chi-square test of the table's tile residuals and their best generic explanation
    (None without table points)."""
    shape = res.table_shape
    if shape is None or len(shape.points_camera) < 100:
        return None
    tiles = shape.tiles()
    y = np.asarray(tiles.mean_m, dtype=np.float64)
    if len(y) < 6:
        return None
    stat = float(np.sum((y / shape.sigma_m) ** 2))
    dof = max(len(y) - 3, 1)
    p = float(chi2.sf(stat, dof))
    r2 = {}
    ranges = {}
    for name in FEATURES:
        if name not in tiles.feature:
            continue
        r2[name], ranges[name] = _quadratic_r2(np.asarray(tiles.feature[name]), y)
    best = max(r2, key=r2.get) if r2 else None
    fitted = np.zeros_like(y)
    if "column" in tiles.feature and "row" in tiles.feature:
        r2["position"], ranges["position"], fitted = _position_fit(
            np.asarray(tiles.feature["column"], dtype=np.float64),
            np.asarray(tiles.feature["row"], dtype=np.float64), y)
        if best is not None and r2["position"] >= r2[best] + POSITION_MARGIN:
            best = "position"
    return StructureFinding(
        chi2=stat, dof=dof, p_value=p, alpha=alpha, structured=bool(p < alpha),
        amplitude_mm=float(np.max(np.abs(y)) * 1000.0), r2_by_feature=r2, best_feature=best,
        best_r2=r2.get(best, 0.0) if best else 0.0,
        best_range_mm=ranges.get(best, 0.0) * 1000.0 if best else 0.0,
        tiles_mm=tuple((y * 1000.0).tolist()),
        centres_px=tuple(map(tuple, np.asarray(tiles.centre_px).tolist())),
        feature_values={k: np.asarray(v).tolist() for k, v in tiles.feature.items()},
        position_fit_mm=tuple((fitted * 1000.0).tolist()))
