"""Rank the candidate effects by BIC and pick the ones the data supports.

Every effect is fitted to the same residuals; its score is ``delta_BIC`` against the
model without it (:attr:`r2s.diagnose.effects.base.EffectFit.delta_bic`) plus its prior
penalty (an effect whose wrong application does harm needs more evidence). An effect is
supported when its score is below ``-min_evidence``; "no effect" wins otherwise. Effects whose
scores lie within ``tie_tolerance`` of the best are indistinguishable on this data; among
them the catalogue's preference decides, and the tie is reported.

With ``max_effects = 2`` the best effect is put into the model (its predicted residuals)
and the remaining effects are fitted again to what is left.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from r2s.console import ProgressFn, silent_progress
from r2s.diagnose.stats.blocks import blocks_of, total_n, total_sse
from r2s.diagnose.data import Residuals
from r2s.diagnose.effects.base import Effect, EffectFit


@dataclass(frozen=True)
class NoiseBar:
    """How the noise-only bar is measured: bootstrap draws, quantile, seed."""

    draws: int = 200
    quantile: float = 0.99
    seed: int = 0


@dataclass(frozen=True)
class Round:
    """One round of ranking: every fit, best first, and which fits the data cannot tell
    from the best (their delta BIC, without prior penalties, within the tie tolerance)."""

    fits: tuple[EffectFit, ...]
    ties: tuple[str, ...] = ()

    @property
    def best(self) -> EffectFit | None:
        return self.fits[0] if self.fits else None


@dataclass(frozen=True)
class Diagnosis:
    """The outcome: the effects chosen (possibly none) and the ranking of each round."""

    rounds: tuple[Round, ...]
    chosen: tuple[EffectFit, ...]
    residuals_before: Residuals = field(repr=False)
    residuals_after: Residuals = field(repr=False)

    @property
    def sse_before(self) -> float:
        return total_sse(blocks_of(self.residuals_before))

    @property
    def sse_after(self) -> float:
        return total_sse(blocks_of(self.residuals_after))

    @property
    def n_obs(self) -> int:
        return total_n(blocks_of(self.residuals_before))


def order_fits(fits: list[EffectFit], effects: dict[str, Effect],
               tie_tolerance: float) -> Round:
    """Best score first; the fits tying with the best are ordered by preference."""
    ok = sorted([f for f in fits if f.identifiable and f.above_noise], key=lambda f: f.score)
    # below the noise bar: what noise alone explains as well; ranked after the rest
    weak = sorted([f for f in fits if f.identifiable and not f.above_noise],
                  key=lambda f: f.score)
    rest = weak + [f for f in fits if not f.identifiable]
    if not ok:
        return Round(tuple(rest))
    best = ok[0].score
    lead = [f for f in ok if f.score <= best + tie_tolerance]
    lead.sort(key=lambda f: (effects[f.effect].preference, f.score))
    tail = [f for f in ok if f.score > best + tie_tolerance]
    first = lead[0]
    # indistinguishable on the data: raw delta BIC (no prior penalty) close to the first's
    same = [first] + [f for f in lead[1:] + tail
                      if abs(f.delta_bic - first.delta_bic) <= tie_tolerance]
    ties = tuple(f.effect for f in same) if len(same) > 1 else ()
    return Round(tuple(lead + tail + rest), ties)


def fit_effect(effect: Effect, residuals: Residuals, penalty: float,
               noise: NoiseBar | None = None, min_evidence: float = 2.0) -> EffectFit:
    """One effect fitted, with its prior penalty and (for an effect whose evidence is in
    the registration block and that passes the BIC bar) the explained SSE noise alone
    reaches in this scene."""
    fit = replace(effect.fit(residuals), penalty=float(penalty))
    if (noise is not None and fit.identifiable and effect.evidence_block == "registration"
            and fit.score < -min_evidence):
        bar = effect.noise_bar(residuals, fit.n_params, noise.draws, noise.quantile,
                               noise.seed)
        fit = replace(fit, noise_bar=bar)
    return fit


def supported(fit: EffectFit | None, min_evidence: float) -> bool:
    """Does the data support ``fit``: identifiable, above what noise alone explains, and
    its score below ``-min_evidence``."""
    return (fit is not None and fit.identifiable and fit.above_noise
            and fit.score < -min_evidence)


def rank(residuals: Residuals, effects: dict[str, Effect], tie_tolerance: float = 2.0,
         penalties: dict[str, float] | None = None, noise: NoiseBar | None = None,
         progress: ProgressFn = silent_progress, min_evidence: float = 2.0) -> Round:
    """Fit every effect of ``effects`` to ``residuals`` and order them (one round)."""
    fits = []
    for k, (name, effect) in enumerate(effects.items()):
        progress(f"fitting {name}", k / max(len(effects), 1))
        fits.append(fit_effect(effect, residuals, (penalties or {}).get(name, effect.penalty),
                               noise, min_evidence))
    return order_fits(fits, effects, tie_tolerance)


def diagnose(residuals: Residuals, effects: dict[str, Effect], max_effects: int = 1,
             min_evidence: float = 2.0, tie_tolerance: float = 2.0,
             progress: ProgressFn = silent_progress,
             penalties: dict[str, float] | None = None,
             noise: NoiseBar | None = None) -> Diagnosis:
    """Fit every effect, rank them, and keep up to ``max_effects`` supported ones, each
    fitted to the residuals the previous ones are predicted to leave (no rerun: the
    stage's loop reruns the stages and measures instead, when it can).

    ``penalties`` overrides effects' prior penalties (BIC units) by name.
    """
    rounds: list[Round] = []
    chosen: list[EffectFit] = []
    current = residuals
    for r in range(max_effects):
        names = {n: e for n, e in effects.items() if n not in {c.effect for c in chosen}}
        rnd = rank(current, names, tie_tolerance, penalties, noise,
                   lambda m, f, r=r: progress(m, (r + f) / max_effects), min_evidence)
        rounds.append(rnd)
        best = rnd.best
        if not supported(best, min_evidence):
            break
        chosen.append(best)
        current = best.residuals_after if best.residuals_after is not None else current
    return Diagnosis(tuple(rounds), tuple(chosen), residuals, current)
