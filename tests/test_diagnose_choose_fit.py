"""The step's effect beside a structure no catalogued effect explains
(:func:`r2s.diagnose.stats.steps.choose_fit`): part of that structure is no evidence for one
effect over another, so such fits compete on their score without the table's shape."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from helpers_diagnose import depth_to_table, pixel_grid
from r2s.diagnose.data import Residuals, TableShapeData
from r2s.diagnose.effects.base import EffectFit
from r2s.diagnose.stats.steps import (block_sse, choose_fit, leaves_structure,
                                      score_without_table_shape, table_shape_fall)
from r2s.geometry.camera import intrinsics, look_at

W, H = 320, 240
K = intrinsics(W, H, 58.0)
ALPHA, MIN_EVIDENCE, TIE = 1e-3, 2.0, 2.0


def decentred_table(p1: float, p2: float, seed: int = 0) -> TableShapeData:
    """A level 0.6 m table seen obliquely through a lens with decentering distortion
    (p1, p2): each true ray x is recorded at x + offset(x) and back-projected from there
    through the ideal K, with 0.3 mm of depth noise."""
    rng = np.random.default_rng(seed)
    world_from_camera = look_at([0.5, -0.35, 0.45], [0.0, 0.0, 0.0])
    _, _, x = pixel_grid(K, W, H)
    z = depth_to_table(x, world_from_camera)
    world = (np.hstack([x, np.ones((len(x), 1))]) * z[:, None]) @ world_from_camera[:3, :3].T
    world += world_from_camera[:3, 3]
    keep = (z > 0) & (np.abs(world[:, 0]) < 0.3) & (np.abs(world[:, 1]) < 0.3)
    a, b = x[:, 0], x[:, 1]
    r2 = a * a + b * b
    xd = x + np.stack([2 * p1 * a * b + p2 * (r2 + 2 * a * a),
                       p1 * (r2 + 2 * b * b) + 2 * p2 * a * b], axis=1)
    z = z + rng.normal(0.0, 0.0003, len(z))
    points = np.hstack([xd * z[:, None], z[:, None]])[keep]
    return TableShapeData(points_camera=points, K=K, width=W, height=H, sigma_m=0.0004)


P = (0.03, -0.045)


def fit_of(effect: str, before: Residuals, after: TableShapeData, score_without: float
           ) -> EffectFit:
    """A fit that predicts ``after`` for the table's shape and whose score without the
    table-shape fall is ``score_without`` (BIC units)."""
    sb = block_sse(before, ("table_shape",))["table_shape"]
    res = Residuals(table_shape=after)
    sa = block_sse(res, ("table_shape",))["table_shape"]
    fit = EffectFit(effect, {}, 1, sb, sa, 45, residuals_after=res)
    return replace(fit, penalty=score_without - (sb - sa) - fit.delta_bic)


@pytest.fixture(scope="module")
def before() -> Residuals:
    return Residuals(table_shape=decentred_table(*P))


def test_a_fit_that_leads_by_part_of_the_structure_gives_way(before):
    # the offset-like fit takes 10 % of the table's structured residual (SSE 238), the
    # scale-like one 3 %; without the table's shape the second is the better by 10
    offset = fit_of("depth_offset", before, decentred_table(0.9 * P[0], 0.9 * P[1]), -30.0)
    scale = fit_of("depth_scale", before, decentred_table(0.97 * P[0], 0.97 * P[1]), -40.0)
    assert table_shape_fall(offset, before) > table_shape_fall(scale, before) + 10.0
    assert offset.score < scale.score   # the round's order: the offset first
    assert score_without_table_shape(offset, before) == pytest.approx(-30.0)
    for f in (offset, scale):  # each leaves the structure and is supported without it
        assert leaves_structure(f, before, ALPHA) is not None
        assert leaves_structure(f, before, ALPHA, min_evidence=MIN_EVIDENCE) is None
    chosen, skipped = choose_fit([offset, scale], before, lambda f: f.score < -MIN_EVIDENCE,
                                 ALPHA, MIN_EVIDENCE, TIE)
    assert chosen is scale
    assert [s["effect"] for s in skipped] == ["depth_offset"]
    assert "-30.0 against depth_scale's -40.0" in skipped[0]["why"]


def test_within_the_tie_tolerance_the_first_stays(before):
    offset = fit_of("depth_offset", before, decentred_table(0.9 * P[0], 0.9 * P[1]), -39.0)
    scale = fit_of("depth_scale", before, decentred_table(0.97 * P[0], 0.97 * P[1]), -40.0)
    chosen, skipped = choose_fit([offset, scale], before, lambda f: f.score < -MIN_EVIDENCE,
                                 ALPHA, MIN_EVIDENCE, TIE)
    assert chosen is offset and skipped == []


def test_a_fit_that_explains_the_structure_is_chosen_first(before):
    flat = decentred_table(0.0, 0.0)
    lens = fit_of("lens_like", before, flat, -10.0)   # takes it all: not a second thing
    scale = fit_of("depth_scale", before, decentred_table(0.97 * P[0], 0.97 * P[1]), -40.0)
    assert lens.score < scale.score
    assert leaves_structure(lens, before, ALPHA) is None
    chosen, _ = choose_fit([lens, scale], before, lambda f: f.score < -MIN_EVIDENCE,
                           ALPHA, MIN_EVIDENCE, TIE)
    assert chosen is lens


def test_nothing_supported_without_the_table_is_nothing_chosen(before):
    # explains part of the structure and nothing else: passed over, as before
    offset = fit_of("depth_offset", before, decentred_table(0.9 * P[0], 0.9 * P[1]), 1.0)
    chosen, skipped = choose_fit([offset], before, lambda f: f.score < -MIN_EVIDENCE,
                                 ALPHA, MIN_EVIDENCE, TIE)
    assert chosen is None
    assert skipped[0]["effect"] == "depth_offset" and "not its cause" in skipped[0]["why"]
