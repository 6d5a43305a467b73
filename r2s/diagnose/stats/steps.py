"""One step of the diagnose loop, judged: did the rerun lower the residual the effect
claimed to explain?

An effect's fit predicts the residual it leaves (``EffectFit.residuals_after``); the
blocks whose SSE it predicts to lower are its *claim*. After the affected stages are
rerun with the effect in the model and the residuals are measured again, the effect is
kept only when the measured SSE of the claimed blocks fell by at least ``min_share`` of
the predicted fall (and by more than ``min_gain``); otherwise it is reverted. An effect is
also not named when the residual it is predicted to leave is still structured
(:mod:`r2s.diagnose.stats.structure_test`) and it explains less than ``min_structure_share``
of the structured block, unless it is supported without that block (the table's
distance, the priors): otherwise it would be the nearest catalogued effect, not the cause.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional, Sequence

from r2s.diagnose.stats.blocks import blocks_of
from r2s.diagnose.data import Residuals
from r2s.diagnose.effects.base import EffectFit
from r2s.diagnose.stats.structure_test import test_structure

CLAIM_MIN_SSE = 0.5
"""A block is claimed when the fit predicts its SSE to fall by more than this."""


def block_sse(res: Optional[Residuals], names: tuple[str, ...]) -> dict[str, float]:
    if res is None:
        return {}
    blocks = blocks_of(res)
    return {n: blocks[n].sse for n in names if n in blocks}


def claimed_blocks(fit: EffectFit, before: Residuals) -> tuple[str, ...]:
    """Blocks whose SSE the fit predicts to fall by more than :data:`CLAIM_MIN_SSE`."""
    if fit.residuals_after is None:
        return ()
    b0, b1 = blocks_of(before), blocks_of(fit.residuals_after)
    return tuple(n for n in b0 if n in b1 and b0[n].sse - b1[n].sse > CLAIM_MIN_SSE)


@dataclass(frozen=True)
class StepJudgement:
    """The claim of one step and what the rerun measured (normalised SSE)."""

    claimed: tuple
    claimed_before: float
    claimed_predicted: float
    claimed_after: Optional[float]
    kept: bool
    reason: str
    flipped: bool = False
    """Reverted because the rerun flipped an object's fit off its support, not because the
    claimed residual stayed."""

    def summary(self) -> dict:
        return {"claimed_blocks": list(self.claimed), "claimed_sse_before": self.claimed_before,
                "claimed_sse_predicted": self.claimed_predicted,
                "claimed_sse_after": self.claimed_after, "kept": self.kept,
                "reason": self.reason, "flipped": self.flipped}


def judge_step(fit: EffectFit, before: Residuals, after: Optional[Residuals],
               min_share: float = 0.25, min_gain: float = 1.0) -> StepJudgement:
    """Keep or revert ``fit`` given the residuals measured after its rerun."""
    claimed = claimed_blocks(fit, before)
    sb = sum(block_sse(before, claimed).values())
    sp = sum(block_sse(fit.residuals_after, claimed).values())
    if after is None:
        return StepJudgement(claimed, sb, sp, None, True, "not rerun: predicted only")
    blocks_after = block_sse(after, claimed)
    sa = sum(blocks_after.values())
    missing = [n for n in claimed if n not in blocks_after]
    predicted_gain, gain = sb - sp, sb - sa
    if missing:
        return StepJudgement(claimed, sb, sp, sa, False,
                             f"the rerun has no {', '.join(missing)} residual to compare")
    if gain > min_gain and gain >= min_share * predicted_gain:
        return StepJudgement(claimed, sb, sp, sa, True,
                             f"the claimed residual fell {sb:.1f} -> {sa:.1f} "
                             f"(predicted {sp:.1f})")
    return StepJudgement(claimed, sb, sp, sa, False,
                         f"reverted: the claimed residual went {sb:.1f} -> {sa:.1f} in the "
                         f"rerun (predicted {sp:.1f})")


def leaves_structure(fit: EffectFit, before: Residuals, alpha: float,
                     min_structure_share: float = 0.8,
                     min_evidence: Optional[float] = None) -> Optional[str]:
    """Why ``fit`` only explains part of a structured residual (None when it does not):
    the residual it predicts to leave in the table's shape is still structured and it
    explains less than ``min_structure_share`` of that block. With ``min_evidence``, an
    effect that is supported without the table's shape (its score with the table-shape
    block's fall taken out still below ``-min_evidence``: the table's distance, the
    priors' sizes) is not passed over: the structure is then a second thing wrong, left
    for the test after the loop, not what the effect was chosen for (a 4 % depth scale
    with a radial depth error: docs/diagnose.md, section 6)."""
    if fit.residuals_after is None or "table_shape" not in claimed_blocks(fit, before):
        return None
    left = test_structure(fit.residuals_after, alpha)
    if left is None or not left.structured:
        return None
    sb = block_sse(before, ("table_shape",)).get("table_shape", 0.0)
    share = table_shape_fall(fit, before) / sb if sb > 0 else 0.0
    if share >= min_structure_share:
        return None
    if min_evidence is not None and score_without_table_shape(fit, before) < -min_evidence:
        return None
    return (f"{fit.effect} explains {100 * share:.0f} % of the table's structured residual "
            f"and leaves it structured (p = {left.p_value:.2g}): not its cause")


def table_shape_fall(fit: EffectFit, before: Residuals) -> float:
    """How much of the table-shape block's SSE (normalised) ``fit`` predicts to remove from
    ``before``, >= 0 (0 without a prediction or a table-shape block)."""
    if fit.residuals_after is None:
        return 0.0
    sb = block_sse(before, ("table_shape",)).get("table_shape", 0.0)
    sa = block_sse(fit.residuals_after, ("table_shape",)).get("table_shape", sb)
    return max(0.0, sb - sa)


def score_without_table_shape(fit: EffectFit, before: Residuals) -> float:
    """``fit.score`` (BIC units, lower is better) with its fall of the table-shape block's
    SSE taken out: the evidence of the other blocks (the table's distance and tilt, the
    priors' sizes, the physics)."""
    return fit.score + table_shape_fall(fit, before)


def choose_fit(fits: Sequence[EffectFit], before: Residuals,
               is_supported: Callable[[EffectFit], bool], alpha: float, min_evidence: float,
               tie_tolerance: float) -> tuple[Optional[EffectFit], list[dict]]:
    """The step's effect of a round's ``fits`` (in the round's order) and the fits passed
    over, with why.

    The first supported fit (``is_supported``) that does not leave a structured residual it
    only partly explains (:func:`leaves_structure`) is chosen, as before, when it leaves
    the table's shape unstructured. When it is supported only as a second thing wrong (it
    leaves the table's residual structured and is supported without the table's shape),
    the fits of that kind compete on :func:`score_without_table_shape` instead: part of a
    structure that no catalogued effect explains is no evidence for one effect over
    another. The lowest wins, or the first in the round's order within ``tie_tolerance``
    of it. Found with a 4 % depth scale and a decentering lens distortion outside the
    catalogue (docs/diagnose.md, section 6): a 21 mm depth offset took 15 % of the lens's
    table residual, the scale 6 %, and the offset led by 21; without the table's shape the
    scale leads by 8 (the priors' sizes; the offset tilts the table)."""
    skipped: list[dict] = []
    second: list[EffectFit] = []
    for fit in fits:
        if not is_supported(fit):
            break
        why = leaves_structure(fit, before, alpha)
        if why is None:
            if not second:
                return fit, skipped
        elif score_without_table_shape(fit, before) < -min_evidence:
            second.append(fit)  # supported without the table: a second thing wrong
        elif not second:
            skipped.append({"effect": fit.effect, "why": why})
    if not second:
        return None, skipped
    scores = [score_without_table_shape(f, before) for f in second]
    best = min(scores)
    k = next(i for i, s in enumerate(scores) if s <= best + tie_tolerance)
    for f, s in zip(second[:k], scores[:k]):
        skipped.append({"effect": f.effect, "why": (
            f"{f.effect} leads by part of a table residual no catalogued effect explains; "
            f"without the table's shape it scores {s:.1f} against {second[k].effect}'s "
            f"{scores[k]:.1f}")})
    return second[k], skipped
