"""Noise levels measured in the scene itself, and what noise alone would make of them.

Priors err in size independently (a few per cent per object); a depth bias moves them all
together. So the spread of the log prior scales about their mean, pooled with a calibrated
prior spread, is the noise level of one prior (:func:`scale_noise_level`), and "noise alone" is the same scales with the common part
removed, drawn again over the objects (a bootstrap: :func:`null_registrations`). An effect
whose evidence lies in the registration block must explain more than the effect fitted to
those draws explains, at the chosen quantile (:func:`noise_bar`): the bar that keeps the
false-alarm rate of the depth effects near ``1 - quantile`` whatever the number of objects.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Iterator

import numpy as np

from r2s.diagnose.data import RegistrationData, Residuals

OUTLIER_MADS = 3.5
"""A log scale farther than this many robust spreads from the median is a misregistration:
it is left out of the spread (the fits are Huber-robust against it too)."""


def scale_noise_level(log_scales: np.ndarray, floor: float, prior_sigma: float = 0.02,
                      prior_dof: float = 4.0) -> tuple[float, float | None]:
    """Noise level of one prior's log scale and its degrees of freedom.

    The sample variance (ddof 1) of the log scales without outliers, pooled with a prior
    spread ``prior_sigma`` worth ``prior_dof`` observations (calibrated on clean scenes:
    docs/diagnose.md), so that 3 objects whose priors happen to agree do not make a tiny
    noise level; at least ``floor``. The sample deviation, unlike the median absolute
    deviation used before, is not biased low for a handful of objects. Returns
    ``(sigma, dof)``; ``dof`` is None when the floor set the level (a known noise level)."""
    x = np.asarray(log_scales, dtype=np.float64)
    if len(x) >= 3:
        med = np.median(x)
        mad = 1.4826 * np.median(np.abs(x - med))
        keep = np.abs(x - med) <= OUTLIER_MADS * max(mad, floor)
        x = x[keep] if keep.sum() >= 3 else x
    m = len(x)
    ss = float(np.sum((x - x.mean()) ** 2)) if m >= 2 else 0.0
    dof = prior_dof + max(m - 1, 0)
    if dof <= 0:
        return float(floor), None
    sigma = float(np.sqrt((prior_dof * prior_sigma ** 2 + ss) / dof))
    if sigma <= floor:
        return float(floor), None
    return sigma, float(dof)


def null_registrations(reg: RegistrationData, draws: int, seed: int = 0
                       ) -> Iterator[RegistrationData]:
    """``draws`` registrations as noise alone would give them: every used object keeps its
    depth, its log scale is one of the centred log scales drawn with replacement (bootstrap
    over objects); the noise level is measured on each draw with the scene's rule."""
    used = reg.used()
    logs = np.log([o.scale for o in used])
    centred = logs - np.mean(logs)
    rng = np.random.default_rng(seed)
    floor = reg.scale_floor if reg.scale_floor is not None else reg.scale_sigma
    for _ in range(draws):
        pick = rng.choice(centred, size=len(centred), replace=True)
        objs = tuple(replace(o, scale=float(np.exp(v))) for o, v in zip(used, pick))
        sigma, dof = scale_noise_level(pick, floor, *reg.noise_prior)
        yield replace(reg, objects=objs, scale_sigma=sigma, noise_dof=dof)


def sampling_bar(reg: RegistrationData, n_params: int, quantile: float) -> float:
    """The explained SSE a ``n_params`` effect reaches on Gaussian noise at ``quantile``
    when the noise level is itself an estimate with ``reg.noise_dof`` degrees of freedom:
    ``k F(k, dof)`` (with 3 objects and the prior worth 4, F(1, 6) at 0.99 gives 13.7; the
    sample alone, F(1, 2), would give 98.5), or ``chi2(k)`` for a known level (the floor)."""
    from scipy.stats import chi2  # about 1 s to import: only where diagnose ranks effects
    from scipy.stats import f as f_dist

    if reg.noise_dof is None:
        return float(chi2.ppf(quantile, n_params))
    return float(n_params * f_dist.ppf(quantile, n_params, reg.noise_dof))


def noise_bar(fit_explained: Callable[[Residuals], float], residuals: Residuals,
              n_params: int = 1, draws: int = 200, quantile: float = 0.99,
              seed: int = 0) -> float | None:
    """The explained SSE that noise alone reaches at ``quantile``: the larger of
    ``fit_explained`` applied to :func:`null_registrations` of the scene (other blocks as
    measured; a bootstrap over objects) and :func:`sampling_bar`. With fewer than 3
    registered objects there is nothing to bootstrap and the sampling bar alone holds
    (two priors that happen to err the same way are not a depth bias: on the benchmark's
    ``offset+friction`` seed 5, two priors named a depth scale before this rule); None
    without any."""
    reg = residuals.registration
    if reg is None or not reg.used():
        return None
    if len(reg.used()) < 3:
        return sampling_bar(reg, n_params, quantile)
    values = [fit_explained(replace(residuals, registration=null))
              for null in null_registrations(reg, draws, seed)]
    boot = float(np.quantile(values, quantile)) if values else 0.0
    return max(boot, sampling_bar(reg, n_params, quantile))


def mixed_sampling_bar(dof: float | None, known_share: float, quantile: float,
                       samples: int = 20000, seed: int = 0) -> float:
    """:func:`sampling_bar` for a one-parameter effect whose estimate combines the prior
    scales (noise level estimated with ``dof`` degrees of freedom; None: known) with a
    second evidence of known noise level (the table's shape) that carries ``known_share``
    of the Fisher information: the ``quantile`` of ``(sqrt(1 - w) t + sqrt(w) z)^2`` with
    ``t`` Student's t (``dof``), ``z`` standard normal, ``w = known_share`` (Monte Carlo,
    seeded). ``w = 0`` gives ``F(1, dof)``, ``w = 1`` gives ``chi2(1)``."""
    w = float(np.clip(known_share, 0.0, 1.0))
    rng = np.random.default_rng(seed)
    t = rng.standard_t(dof, samples) if dof is not None else rng.standard_normal(samples)
    z = rng.standard_normal(samples)
    return float(np.quantile((np.sqrt(1.0 - w) * t + np.sqrt(w) * z) ** 2, quantile))
