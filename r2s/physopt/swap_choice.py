"""Keep the prior or the completion? The choice between physopt's two solutions of a scene.

physopt solves a scene with the registered priors; where a prior object can be made to rest
only beyond the observation tolerance, it solves again with init's completion of that
object in its place (r2s/stages/physopt.py). The second solution is kept only when it is no
worse at resting (no more objects still moving, no more flagged) and better in view: its
pooled silhouette IoU against the input masks is higher by at least ``MIN_IOU_GAIN``. Fewer
flags alone are not enough:
on the seed demo (real SAM 3D priors) the completions left 1 object flagged instead of 3,
but physopt moved the others more and the scene's IoU fell from 0.784 to 0.526. Without an
input view (no masks to compare with), fewer flags decide.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

MIN_IOU_GAIN = 0.01
"""A prior carries the hidden side a completion only guesses, so the completions must be
clearly better in view. Set on the realistic benchmark's and the held-out scenes where
physopt tried the swap: gains of 0.031-0.110 came with CD against gt the same or lower;
on the realistic scene_00 a gain of 0.004 came with CD 7.7 -> 13.5 mm (its priors were
closer to gt than their completions)."""


@dataclass(frozen=True)
class SolutionSummary:
    """What decides between two solutions of one scene.

    flagged : objects beyond the observation tolerance; moving : objects still moving;
    pooled_iou : silhouette IoU of the whole scene against the input masks (None: no view).
    """

    flagged: int
    moving: int
    pooled_iou: Optional[float]


def prefer_swapped(with_priors: SolutionSummary, with_completions: SolutionSummary) -> bool:
    """True when the solution with completions should replace the one with priors."""
    if (with_completions.moving > with_priors.moving
            or with_completions.flagged > with_priors.flagged):
        return False
    if with_priors.pooled_iou is not None and with_completions.pooled_iou is not None:
        return with_completions.pooled_iou >= with_priors.pooled_iou + MIN_IOU_GAIN
    return with_completions.flagged < with_priors.flagged
