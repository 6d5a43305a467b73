"""Camera or table: which of the two effects that tilt the fitted table was named, and why.

A few degrees between the fitted table normal and the declared vertical is, a priori, a
camera extrinsic error 4 times in 5 and a tilted table once (docs/diagnose.md, section 3):
``table_tilt`` carries ``2 ln(odds)`` BIC units against ``camera_rotation``; the rollout
can outweigh that. This module writes the choice, the alternative and the numbers for the
report.
"""

from __future__ import annotations

import numpy as np


def camera_or_table(first_round, kept: list, prior_odds: float) -> dict | None:
    """The camera-or-table choice of the first ranking, for the report: which of
    ``camera_rotation`` / ``table_tilt`` was named (or led, when neither was kept), the
    other as the alternative, their scores, the prior, and gravity in the declared world
    frame (with a camera correction the exported world is the corrected one, where gravity
    is -z; in the declared frame it is the correction's inverse applied to -z)."""
    if first_round is None:
        return None
    fits = {f.effect: f for f in first_round.fits
            if f.effect in ("camera_rotation", "table_tilt") and f.identifiable}
    if len(fits) < 2:
        return None
    names = [f.effect for f in kept]
    if "camera_rotation" in names or "table_tilt" in names:
        choice = "camera_rotation" if "camera_rotation" in names else "table_tilt"
    elif fits["camera_rotation"].size is None or fits["camera_rotation"].size < 0.5:
        return None
    else:
        choice = min(fits, key=lambda n: fits[n].score)
    other = "table_tilt" if choice == "camera_rotation" else "camera_rotation"
    out = {"choice": choice, "alternative": other, "kept": choice in names,
           "score": {n: f.score for n, f in fits.items()},
           "delta_bic": {n: f.delta_bic for n, f in fits.items()},
           "prior_odds_camera_to_table": prior_odds,
           "why": (f"prior odds {prior_odds:g}:1 for a camera error (table_tilt carries "
                   f"{2 * np.log(prior_odds):.2f} BIC units); scores camera "
                   f"{fits['camera_rotation'].score:.1f}, table {fits['table_tilt'].score:.1f}")}
    corr = fits["camera_rotation"].params.get("world_correction")
    if choice == "camera_rotation" and corr is not None:
        rot = np.asarray(corr, dtype=np.float64)[:3, :3]
        out["gravity_declared_world"] = (rot.T @ np.array([0.0, 0.0, -9.81])).tolist()
        out["gravity_exported_world"] = [0.0, 0.0, -9.81]
    return out
