"""A depth offset seen in the table's shape: a constant offset bends an obliquely seen
plane (``n . p' = d z' / (z' - o)``), a depth scale keeps it a plane, a radial lens
distortion bends it into a bowl about the principal point. Hand-made table point clouds
with known effects against the fits."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2
from scipy.stats import f as f_dist

from helpers_diagnose import depth_to_table, pixel_grid

from r2s.diagnose.data import RegistrationData, Residuals, ScaleObs, TableShapeData
from r2s.diagnose.effects import get_effect
from r2s.diagnose.stats.noise import mixed_sampling_bar
from r2s.diagnose.stats.ranking import NoiseBar, fit_effect, supported
from r2s.diagnose.stats.steps import leaves_structure
from r2s.diagnose.stats.table_offset import (corrected_table, offset_evidence,
                                             table_offset_evidence)
from r2s.geometry.camera import intrinsics, look_at
from r2s.geometry.lens import undistort_normalised

W, H = 320, 240
K = intrinsics(W, H, 58.0)
TABLE_HALF_M = 0.3
"""The table is 0.6 m square, centred in the camera's view."""


def table_points(offset_m: float = 0.0, scale: float = 1.0, k1: float = 0.0,
                 row_error_m: float = 0.0, noise_m: float = 0.0003,
                 seed: int = 0) -> np.ndarray:
    """(N, 3) camera-frame points of a level table seen obliquely (depths about 0.45 to
    0.85 m, like the benchmark's cameras), as a sensor with depth ``scale * z + offset``
    (plus ``row_error_m`` x the squared row offset from the centre) and a lens ``k1``
    back-projects them through the ideal K."""
    rng = np.random.default_rng(seed)
    world_from_camera = look_at([0.5, -0.35, 0.45], [0.0, 0.0, 0.0])
    _, v, xd = pixel_grid(K, W, H)
    x = undistort_normalised(xd, k1)
    rays = np.hstack([x, np.ones((len(x), 1))])
    z = depth_to_table(x, world_from_camera)
    world = (rays * z[:, None]) @ world_from_camera[:3, :3].T + world_from_camera[:3, 3]
    on_table = (z > 0) & (np.abs(world[:, 0]) < TABLE_HALF_M) & (np.abs(world[:, 1]) < TABLE_HALF_M)
    rows = (v - (H - 1) / 2) / ((H - 1) / 2)
    z = scale * z + offset_m + row_error_m * rows ** 2 + rng.normal(0.0, noise_m, len(z))
    ok = on_table & (z > 0)
    return np.hstack([xd * z[:, None], z[:, None]])[ok]


def shape(points: np.ndarray) -> TableShapeData:
    return TableShapeData(points_camera=points, K=K, width=W, height=H, sigma_m=0.0004)


def test_the_table_depths_span_what_the_benchmark_cameras_see():
    z = table_points()[:, 2]
    assert 0.40 < np.percentile(z, 5) < 0.55 and 0.75 < np.percentile(z, 95) < 1.0


@pytest.mark.parametrize("offset_m", [0.01, -0.015])
def test_table_shape_gives_a_known_offset_within_20_percent(offset_m):
    ev = table_offset_evidence(shape(table_points(offset_m=offset_m)))
    assert ev is not None
    assert ev.offset_m == pytest.approx(offset_m, rel=0.2)
    assert abs(ev.offset_m / ev.sigma_m) > 3.0   # clearly seen at this size
    # correcting it leaves a flat table: the noise alone
    flat = table_offset_evidence(corrected_table(shape(table_points(offset_m=offset_m)),
                                                 1.0, ev.offset_m))
    assert abs(flat.offset_m) < 0.2 * abs(offset_m)


def test_depth_offset_is_fitted_from_the_table_alone():
    """No metric prior: the table's shape identifies the offset (never the scale)."""
    res = Residuals(table_shape=shape(table_points(offset_m=0.012)))
    fit = get_effect("depth_offset").fit(res)
    assert fit.identifiable
    assert fit.params["offset_m"] == pytest.approx(0.012, rel=0.2)
    assert fit.delta_bic < -2.0
    assert not get_effect("depth_scale").fit(res).identifiable
    # the noise bar without priors is the chi-square quantile of the table's own estimate
    ranked = fit_effect(get_effect("depth_offset"), res, 0.0, NoiseBar(draws=100))
    assert ranked.noise_bar == pytest.approx(chi2.ppf(0.99, 1), rel=0.1)
    assert supported(ranked, 2.0)


def test_table_shape_tells_an_offset_from_a_scale_and_a_lens():
    # a depth scale keeps the table a plane: no offset seen
    scaled = table_offset_evidence(shape(table_points(scale=1.04)))
    assert abs(scaled.offset_m) < 0.5 * scaled.sigma_m and abs(scaled.offset_m) < 0.001
    # a lens bowl: the lens explains it all, an offset a part only, so the lens ranks first
    # and, once it is in the model, no offset is left in the table
    lens = Residuals(table_shape=shape(table_points(k1=-0.12)))
    lens_fit = get_effect("lens_distortion").fit(lens)
    off_on_lens = get_effect("depth_offset").fit(lens)
    assert lens_fit.explained_sse > 0.9 * offset_evidence(lens.table_shape).sse_at_zero
    assert off_on_lens.explained_sse < 0.7 * lens_fit.explained_sse
    left = table_offset_evidence(lens_fit.residuals_after.table_shape)
    assert left is None or abs(left.offset_m) < 0.002
    # an offset is not a lens bowl
    offset = Residuals(table_shape=shape(table_points(offset_m=0.012)))
    lens_on_offset = get_effect("lens_distortion").fit(offset)
    off_fit = get_effect("depth_offset").fit(offset)
    assert lens_on_offset.explained_sse < 0.8 * off_fit.explained_sse


def _priors(offset_m: float, sigma: float = 0.002, n: int = 8) -> RegistrationData:
    z = np.linspace(0.45, 0.9, n)
    objs = tuple(ScaleObs(id=i + 1, scale=float(1.0 + offset_m / (zi - offset_m)), depth_m=zi)
                 for i, zi in enumerate(z))
    return RegistrationData(objects=objs, scale_sigma=sigma)


def test_table_and_priors_combine_when_they_agree_and_not_when_they_disagree():
    table = shape(table_points(offset_m=0.01))
    agree = get_effect("depth_offset").fit(Residuals(registration=_priors(0.01),
                                                     table_shape=table))
    assert agree.params["offset_m"] == pytest.approx(0.01, rel=0.1)
    assert "the table's shape alone" in agree.note
    # tight priors that see no offset: the table is bent by something else
    disagree = get_effect("depth_offset").fit(Residuals(registration=_priors(0.0),
                                                        table_shape=table))
    assert "disagree" in disagree.note
    assert abs(disagree.params["offset_m"]) < 0.001


def test_a_row_pattern_is_not_taken_for_an_offset_the_priors_do_not_see():
    """The uncatalogued depth error that grows with the squared image row bends this
    table much as a 2 cm offset would (on the benchmark's cameras it asks for 6-7 cm,
    beyond a sensor's offset); metric priors that see no offset (six, 2 % size errors)
    disagree, so the table is no evidence, and the offset is not named for it."""
    table = shape(table_points(row_error_m=0.006))
    alone = table_offset_evidence(table)
    assert alone.offset_m > 0.015   # the ambiguity this guards against
    res = Residuals(registration=_priors(0.0, sigma=0.02, n=6), table_shape=table)
    eff = get_effect("depth_offset")
    used, why = eff.table_evidence(res)
    assert used is None and "disagree" in why
    fit = fit_effect(eff, res, 0.0, NoiseBar(draws=50))
    assert not supported(fit, 2.0)


def test_mixed_sampling_bar_spans_f_and_chi_square():
    assert mixed_sampling_bar(6.0, 0.0, 0.99, samples=200000) == pytest.approx(
        f_dist.ppf(0.99, 1, 6.0), rel=0.03)
    assert mixed_sampling_bar(6.0, 1.0, 0.99, samples=200000) == pytest.approx(
        chi2.ppf(0.99, 1), rel=0.03)
    mid = mixed_sampling_bar(6.0, 0.5, 0.99, samples=200000)
    assert chi2.ppf(0.99, 1) < mid < f_dist.ppf(0.99, 1, 6.0)


def test_priors_seen_by_too_few_points_are_left_out_of_the_scale_evidence():
    """Four well-seen priors agree on a 4 % scale; one seen by 46 points (its scale fit
    off by 30 %, as on the benchmark's small occluded objects) is no evidence."""
    from r2s.diagnose.measure.observe import FitQuality, registration_residual

    seen = {i: FitQuality(ScaleObs(id=i, scale=s, depth_m=0.6, fitness=0.95, n_points=n),
                          0.95, 0.001)
            for i, s, n in ((1, 1.035, 1500), (2, 1.045, 900), (3, 1.04, 1200),
                            (4, 1.042, 700), (5, 0.74, 46))}
    strict = registration_residual(seen, 0.01, 0.6, min_points=150)
    loose = registration_residual(seen, 0.01, 0.6, min_points=0)
    assert [o.id for o in strict.used()] == [1, 2, 3, 4]
    assert len(loose.used()) == 5
    eff = get_effect("depth_scale")
    fit = fit_effect(eff, Residuals(registration=strict), 0.0, NoiseBar(draws=200))
    assert fit.params["scale"] == pytest.approx(1.0405, abs=0.003)
    # the badly seen one, drawn again and again by the bootstrap, makes noise look like a
    # common scale: the bar with it is higher
    with_it = fit_effect(eff, Residuals(registration=loose), 0.0, NoiseBar(draws=200))
    assert fit.noise_bar < 0.5 * with_it.noise_bar
    assert supported(fit, 2.0) and not supported(with_it, 2.0)
