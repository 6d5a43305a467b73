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
from typing import Optional

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
    sa = block_sse(fit.residuals_after, ("table_shape",)).get("table_shape", 0.0)
    share = (sb - sa) / sb if sb > 0 else 0.0
    if share >= min_structure_share:
        return None
    if min_evidence is not None and fit.score + max(0.0, sb - sa) < -min_evidence:
        return None
    return (f"{fit.effect} explains {100 * share:.0f} % of the table's structured residual "
            f"and leaves it structured (p = {left.p_value:.2g}): not its cause")
