"""Noise levels measured in the scene itself, and what noise alone would make of them.

Priors err in size independently (a few per cent per object); a depth bias moves them all
together. So the spread of the log prior scales about their mean is the noise level of one
prior (:func:`scale_noise_level`), and "noise alone" is the same scales with the common part
removed, drawn again over the objects (a bootstrap: :func:`null_registrations`). An effect
whose evidence lies in the registration block must explain more than the effect fitted to
those draws explains, at the chosen quantile (:func:`noise_bar`): the bar that keeps the
false-alarm rate of the depth effects near ``1 - quantile`` whatever the number of objects.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Iterator

import numpy as np
from scipy.stats import chi2
from scipy.stats import f as f_dist

from r2s.diagnose.data import RegistrationData, Residuals

OUTLIER_MADS = 3.5
"""A log scale farther than this many robust spreads from the median is a misregistration:
it is left out of the spread (the fits are Huber-robust against it too)."""


def scale_noise_level(log_scales: np.ndarray, floor: float) -> float:
    """Noise level of one prior's log scale: the larger of ``floor`` and the sample
    standard deviation (ddof 1) of the log scales without outliers. The sample deviation,
    unlike the median absolute deviation used before, is not biased low for a handful of
    objects (with 6 objects the MAD was below half the true spread in one scene of 4)."""
    x = np.asarray(log_scales, dtype=np.float64)
    if len(x) < 3:
        return float(floor)
    med = np.median(x)
    mad = 1.4826 * np.median(np.abs(x - med))
    keep = np.abs(x - med) <= OUTLIER_MADS * max(mad, floor)
    if keep.sum() < 3:
        keep = np.ones(len(x), dtype=bool)
    return float(max(floor, np.std(x[keep], ddof=1)))


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
        yield RegistrationData(objects=objs, scale_sigma=scale_noise_level(pick, floor),
                               min_fitness=reg.min_fitness, scale_floor=floor)


def sampling_bar(reg: RegistrationData, n_params: int, quantile: float) -> float:
    """The explained SSE a ``n_params`` effect reaches on Gaussian noise at ``quantile``
    when the noise level was measured on the same ``n`` objects: ``k F(k, n - 1)`` (the
    spread of a handful of objects is itself uncertain: with 4 objects the 99 % bar is 29,
    not the 6.6 of a known noise level), or ``chi2(k)`` when the floor set the level."""
    n = len(reg.used())
    floor = reg.scale_floor if reg.scale_floor is not None else reg.scale_sigma
    if reg.scale_sigma <= floor * (1.0 + 1e-9) or n < 3:
        return float(chi2.ppf(quantile, n_params))
    return float(n_params * f_dist.ppf(quantile, n_params, n - 1))


def noise_bar(fit_explained: Callable[[Residuals], float], residuals: Residuals,
              n_params: int = 1, draws: int = 200, quantile: float = 0.99,
              seed: int = 0) -> float | None:
    """The explained SSE that noise alone reaches at ``quantile``: the larger of
    ``fit_explained`` applied to :func:`null_registrations` of the scene (other blocks as
    measured; a bootstrap over objects) and :func:`sampling_bar`. None without at least 3
    registered objects."""
    reg = residuals.registration
    if reg is None or len(reg.used()) < 3:
        return None
    values = [fit_explained(replace(residuals, registration=null))
              for null in null_registrations(reg, draws, seed)]
    boot = float(np.quantile(values, quantile)) if values else 0.0
    return max(boot, sampling_bar(reg, n_params, quantile))
