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
from r2s.diagnose.blocks import blocks_of, total_n, total_sse
from r2s.diagnose.data import Residuals
from r2s.diagnose.effects.base import Effect, EffectFit


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
    ok = sorted([f for f in fits if f.identifiable], key=lambda f: f.score)
    rest = [f for f in fits if not f.identifiable]
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


def diagnose(residuals: Residuals, effects: dict[str, Effect], max_effects: int = 1,
             min_evidence: float = 2.0, tie_tolerance: float = 2.0,
             progress: ProgressFn = silent_progress,
             penalties: dict[str, float] | None = None) -> Diagnosis:
    """Fit every effect, rank them, and keep up to ``max_effects`` supported ones.

    ``penalties`` overrides effects' prior penalties (BIC units) by name.
    """
    rounds: list[Round] = []
    chosen: list[EffectFit] = []
    current = residuals
    for r in range(max_effects):
        fits = []
        names = [n for n in effects if n not in {c.effect for c in chosen}]
        for k, name in enumerate(names):
            progress(f"fitting {name}", (r + k / max(len(names), 1)) / max_effects)
            fit = effects[name].fit(current)
            penalty = (penalties or {}).get(name, effects[name].penalty)
            fits.append(replace(fit, penalty=float(penalty)))
        rnd = order_fits(fits, effects, tie_tolerance)
        rounds.append(rnd)
        best = rnd.best
        if best is None or not best.identifiable or best.score >= -min_evidence:
            break
        chosen.append(best)
        current = best.residuals_after if best.residuals_after is not None else current
    return Diagnosis(tuple(rounds), tuple(chosen), residuals, current)
