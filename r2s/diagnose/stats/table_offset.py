"""The table's shape as evidence of a depth offset, independent of the priors.

A constant depth offset ``o`` (``z_obs = z + o``, z the camera z-depth) moves every
point along its ray by ``o``. A table plane ``n . p = d`` then becomes
``n . p' = d z' / (z' - o)``: not a plane when the camera looks at the table obliquely
(its points span a range of depths), and the bend grows with ``o``. A depth *scale* maps
a plane to a plane (it says nothing here), and a radial lens distortion bends the table
into a bowl about the principal point (a different pattern: the fits separate, see
docs/diagnose.md). The table-shape block (:func:`r2s.diagnose.stats.blocks.table_shape_block`)
measures the bend; its SSE as a function of the offset corrected away is close to a
parabola, ``SSE(o) = SSE_min + ((o - o_T) / sigma_T)^2``, whose vertex ``o_T`` is the
table's estimate and ``sigma_T`` its standard error (the block is a chi-square).

The configured tile noise (``sigma_m`` of the data, 0.4 mm) leaves room for a real table's
flatness; the benchmark's synthetic tables scatter by about 0.2 mm per tile, so ``sigma_T``
from it is about twice too wide and a 1 cm offset seen over a short range of depths falls
under the bar. :func:`table_noise_level` measures the scene's own tile scatter about the
flattest correction and pools it with the configured level (worth
:data:`NOISE_PRIOR_TILES` tiles), like the priors' noise level
(:func:`r2s.diagnose.stats.noise.scale_noise_level`); :func:`with_measured_noise` gives
the data at that level, which the depth effects use for the table's evidence. A table
bent by something else (a lens, a row error) keeps a large scatter after the best offset,
so its level rises and an offset is held to more evidence there.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Optional

import numpy as np

from r2s.diagnose.data import TableShapeData
from r2s.diagnose.stats.blocks import table_shape_block

GRID_STEP_M = 0.005
GRID_LIMIT_M = 0.05
"""The offsets at which the table-shape SSE is evaluated: every 5 mm up to 5 cm either way."""

MAX_TABLE_OFFSET_M = 0.03
"""A table that asks for a larger offset is bent by something else (a depth error that
depends on the image row bends it the same way, docs/diagnose.md section 6): the catalogue
holds sensor offsets of up to a few centimetres."""


NOISE_PRIOR_TILES = 10.0
"""How many tiles' worth the configured tile noise counts for when it is pooled with the
scene's measured tile scatter (:func:`table_noise_level`)."""

PLANE_AND_OFFSET_PARAMS = 4
"""Parameters fitted to the tile means before their scatter is measured: the plane (3)
and the offset (1)."""


@dataclass(frozen=True)
class TableOffsetEvidence:
    """What the table's shape says about a depth offset.

    offset_m : the offset whose correction makes the table flattest (parabola vertex), m.
    sigma_m : its standard error (from the parabola's curvature; chi-square units), m.
    sse_at_zero : the table-shape SSE with no correction.
    """

    offset_m: float
    sigma_m: float
    sse_at_zero: float

    def explained(self, offset_m: float) -> float:
        """Table-shape SSE the correction ``offset_m`` removes, on the parabola."""
        return float((self.offset_m ** 2 - (offset_m - self.offset_m) ** 2)
                     / self.sigma_m ** 2)


def corrected_table(shape: TableShapeData, scale: float, offset_m: float) -> TableShapeData:
    """``shape`` with its points corrected by the depth bias: each moved along its ray to
    the depth ``(z - o) / s``."""
    p = np.asarray(shape.points_camera, dtype=np.float64)
    z = p[:, 2:3]
    return replace(shape, points_camera=p / z * (z - offset_m) / scale)


def _sse(shape: TableShapeData, offset_m: float) -> float:
    return table_shape_block(corrected_table(shape, 1.0, offset_m)).sse


def _vertex(sse_minus: float, sse_mid: float, sse_plus: float, step_m: float
            ) -> tuple[float, float]:
    """(vertex offset from the middle point, curvature) of the parabola through three
    equally spaced SSE values."""
    curvature = (sse_minus - 2.0 * sse_mid + sse_plus) / (2.0 * step_m ** 2)
    if not np.isfinite(curvature) or curvature <= 0:
        return 0.0, 0.0
    return float(-(sse_plus - sse_minus) / (2.0 * step_m) / (2.0 * curvature)), float(curvature)


def table_offset_evidence(shape: Optional[TableShapeData], step_m: float = GRID_STEP_M,
                          limit_m: float = GRID_LIMIT_M) -> Optional[TableOffsetEvidence]:
    """The offset whose correction makes the table flattest and its standard error.

    The table-shape SSE is evaluated on a grid of offsets (``step_m`` apart, up to
    ``limit_m`` either way; the block's soft cap makes the SSE far from its minimum
    flatter than a parabola, so a parabola about zero alone would be biased); the
    parabola through the best grid point and its neighbours gives the vertex, and a
    parabola about the vertex gives the curvature, so ``sigma_T``. None without a table,
    or when the SSE does not curve up there (the table's depths span too little to see
    an offset). A best grid point at the end of the grid is returned as it is: far
    outside any sensor's offset (:data:`MAX_TABLE_OFFSET_M`)."""
    if shape is None or len(shape.points_camera) < 100:
        return None
    grid = np.arange(-limit_m, limit_m + 0.5 * step_m, step_m)
    sse = np.array([_sse(shape, o) for o in grid])
    k = int(np.argmin(sse))
    sse0 = float(sse[int(np.argmin(np.abs(grid)))])
    if k == 0 or k == len(grid) - 1:
        return TableOffsetEvidence(float(grid[k]), float("inf"), sse0)
    move, curvature = _vertex(sse[k - 1], sse[k], sse[k + 1], step_m)
    if curvature <= 0:
        return None
    centre = float(grid[k] + np.clip(move, -step_m, step_m))
    _, curvature_at = _vertex(_sse(shape, centre - step_m), _sse(shape, centre),
                              _sse(shape, centre + step_m), step_m)
    if curvature_at > 0:
        curvature = curvature_at
    return TableOffsetEvidence(offset_m=centre, sigma_m=float(1.0 / np.sqrt(curvature)),
                               sse_at_zero=sse0)


_EVIDENCE_KEY = "_r2s_offset_evidence"
"""Where :func:`offset_evidence` keeps its result on the (frozen) data object."""


def offset_evidence(shape: Optional[TableShapeData]) -> Optional[TableOffsetEvidence]:
    """:func:`table_offset_evidence` of ``shape``, computed once per data object (kept in
    its ``__dict__``, as ``functools.cached_property`` does; the data stays frozen)."""
    if shape is None:
        return None
    if _EVIDENCE_KEY not in shape.__dict__:
        shape.__dict__[_EVIDENCE_KEY] = table_offset_evidence(shape)
    return shape.__dict__[_EVIDENCE_KEY]


def table_noise_level(shape: TableShapeData, offset_m: float,
                      prior_tiles: float = NOISE_PRIOR_TILES) -> tuple[float, float]:
    """Noise level (m) of one tile mean and its degrees of freedom: the scatter of the
    tile means about the plane fitted to the table corrected by ``offset_m`` (the
    flattest correction), ``T - 4`` degrees of freedom for T tiles, pooled with the
    configured ``shape.sigma_m`` worth ``prior_tiles`` tiles:
    ``sqrt((prior_tiles sigma^2 + sum(mean_t^2)) / (prior_tiles + T - 4))``."""
    means = np.asarray(corrected_table(shape, 1.0, offset_m).tiles().mean_m, dtype=np.float64)
    dof = max(len(means) - PLANE_AND_OFFSET_PARAMS, 0)
    total = prior_tiles + dof
    if total <= 0:
        return float(shape.sigma_m), 0.0
    ss = float(np.sum(means ** 2)) if dof > 0 else 0.0
    return float(np.sqrt((prior_tiles * shape.sigma_m ** 2 + ss) / total)), float(total)


def with_measured_noise(shape: Optional[TableShapeData]) -> Optional[TableShapeData]:
    """``shape`` with its tile noise set to :func:`table_noise_level` at the offset that
    makes the table flattest (unchanged without offset evidence, or when the flattest
    offset lies at the end of the grid: bent by something else)."""
    if shape is None:
        return None
    ev = offset_evidence(shape)
    if ev is None or not np.isfinite(ev.sigma_m):
        return shape
    sigma, _ = table_noise_level(shape, ev.offset_m)
    return replace(shape, sigma_m=sigma)
