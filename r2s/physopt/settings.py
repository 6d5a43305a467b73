"""physopt's settings, one pydantic model per part of the algorithm (field docs become
``r2s physopt --help``; the stage's ``Options`` is made of them).

Frames and units as in :mod:`r2s.physopt.params`.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from r2s.metrics.observation_check import SEEN_TOLERANCE_DEG, SEEN_TOLERANCE_M
from r2s.physopt.params import Drift, moving_objects


class RepairSettings(BaseModel):
    """The PyBullet check-and-repair rounds (:mod:`r2s.physopt.repair`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    support_friction: float = Field(0.9, gt=0, description="Friction of the support plane.")
    friction_bounds: tuple[float, float] = Field(
        (0.2, 1.0), description="Per-body friction bounds (PyBullet multiplies two bodies').")
    verify_duration_s: float = Field(
        5.0, gt=0, description="Rollout length of the check (longer than the judge's 3 s: "
                               "slow creep shows late).")
    tolerance_m: float = Field(0.005, gt=0, description="Largest COM motion counted as at rest.")
    tolerance_deg: float = Field(2.0, gt=0, description="Largest rotation counted as at rest.")
    judge_translation_m: float = Field(0.05, gt=0, description="The judge's stability criterion, "
                                                               "translation (ranks rounds).")
    judge_rotation_deg: float = Field(5.0, gt=0, description="The judge's criterion, rotation.")
    max_rounds: int = Field(6, ge=0, description="Verification rounds (friction, then settling).")
    settle_duration_s: float = Field(2.0, gt=0, description="Quasi-static settling time per round.")
    settle_reset_steps: int = Field(8, ge=1, description="Velocities are zeroed every this many "
                                                         "steps while settling.")
    max_com_step_m: float = Field(0.01, gt=0, description="Largest COM move per round.")
    com_repair: bool = Field(True, description="In verification rounds, move a mover's COM "
                                               "over its support and down (see r2s.physopt.repair.com_repair).")
    undo_falling_repairs: bool = Field(
        True, description="In the observation-bounded rounds, undo a mover's COM and friction "
                          "repair when it makes the object fall: its check drift reaches "
                          "judge_translation_m, which it did not before (see "
                          "r2s.physopt.repair).")
    undo_tipping_repairs: bool = Field(
        False, description="With undo_falling_repairs, also undo a repair that makes a mover "
                           "fail the judge's rotation or translation criterion it passed "
                           "before (off: measured, no gain; docs/physopt.md).")
    max_settle_shift_m: float = Field(
        0.03, gt=0, description="In early rounds, a settled object that moved further is kept "
                                "at its pose (its neighbours may still settle).")
    final_settle_shift_m: float = Field(
        0.15, gt=0, description="In the last round, the largest settling move accepted; an "
                                "object that must move further is reported unresolved.")
    rest_duration_s: float = Field(
        4.0, ge=0, description="Last resort when the rounds (max_rounds > 0) run out with "
                               "objects moving: damped full dynamics for this long, then one "
                               "more check (0: off).")
    rest_damping: float = Field(0.9, ge=0, le=1, description="Velocity loss per second in "
                                                             "that damped settling.")
    observation_tolerance_m: float = Field(
        SEEN_TOLERANCE_M, gt=0, description="An object that ends farther than this from its init pose "
                                "(where it was seen) is flagged, not silently moved, m; the "
                                "observation-bounded repairs keep objects within it.")
    observation_tolerance_deg: float = Field(
        SEEN_TOLERANCE_DEG, gt=0, description="... or turned more than this from its init pose, degrees.")
    repair_tolerance_m: float = Field(
        0.005, gt=0, description="The first, tightest tier of the observation-bounded repairs: "
                                 "settling and rest may not carry an object farther than this "
                                 "from where it was seen, m (the next tier allows "
                                 "observation_tolerance_m when objects still move).")
    repair_tolerance_deg: float = Field(
        3.0, gt=0, description="... nor turn it more than this, degrees.")
    observation_bound: bool = Field(
        True, description="Repair first within the observation tolerance (settling and the "
                          "damped rest may not carry an object beyond it); the unbounded "
                          "repairs run only when that leaves an object failing the judge "
                          "(see r2s.physopt.repair.verify_and_repair).")
    foot_height_m: float = Field(
        0.0, ge=0, description="Objects that move in the first check get a flat foot: "
                               "the slice of their collision pieces this far above their "
                               "lowest point, projected down to it (r2s/physopt/"
                               "contact_foot.py; the visual mesh is untouched; 0: off, the "
                               "default: measured, no gain; docs/physopt.md).")
    support_props: bool = Field(
        True, description="Where the solve leaves an object that fell off another in its "
                          "first check flagged or moving, solve the scene again with a "
                          "hidden convex prop on that other under it, where the camera did "
                          "not see, and keep the better solution (r2s/physopt/"
                          "support_prop.py; the visual meshes are untouched).")
    pull_back: bool = Field(
        True, description="Once the repaired scene rests, put the poses the solve changed "
                          "after depenetration back towards its start (all, all but what "
                          "then moves, halfway), keeping the first that still rests "
                          "(r2s/physopt/pull_back.py); COM, mass and friction stay tuned.")
    pull_back_to_seen: bool = Field(
        True, description="Before the start poses, try the poses where init saw the objects "
                          "(all, then all but what then moves), undoing geomopt's moves and "
                          "the depenetration where the judge finds that the scene still "
                          "rests (r2s/physopt/pull_back.py; off: the behaviour before "
                          "2026-11-29).")
    pull_back_one_by_one: bool = Field(
        True, description="Then each object still away from where it was seen, farthest "
                          "first, alone back at that pose or halfway, the others where they "
                          "are, kept where the scene still rests (at most 12 checks; "
                          "r2s/physopt/pull_back.py).")
    free_attempt_severity: float = Field(
        0.0, ge=0, description="physopt redoes the repairs from the start without the "
                               "observation bound when the bounded ones leave an object whose "
                               "check drift is at least this fraction of the judge's criterion "
                               "(0, the default: whenever an object still moves; 0.5 measured, "
                               "not adopted: docs/physopt.md; r2s.physopt.solve."
                               "repair_bounded_then_free).")
    fallback_severity: float = Field(
        0.5, gt=0, description="The unbounded repairs run when an object's check drift is at "
                               "least this fraction of the judge's criterion after the "
                               "observation-bounded ones.")

    def moving(self, drifts: Drift) -> list[int]:
        """Ids whose drift exceeds the at-rest tolerance."""
        return moving_objects(drifts, self.tolerance_m, self.tolerance_deg)


class DiffsimSettings(BaseModel):
    """The per-object step through the differentiable simulator
    (:mod:`r2s.physopt.object_opt`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    diffsim_iterations: int = Field(30, ge=0, description="Adam steps per object.")
    diffsim_samples: int = Field(300, ge=10, description="Surface samples of the free body.")
    diffsim_sdf_resolution: int = Field(48, ge=16, description="SDF grid of fixed neighbours.")
    contact_margin_m: float = Field(0.0015, gt=0, description="Distance that may carry load in "
                                                           "the wrench residual.")
    wrench_tolerance: float = Field(0.01, ge=0, description="Residual counted as balanced.")
    sim_steps: int = Field(20, ge=0, description="Rollout steps of L_sim (0: wrench only).")
    sim_every: int = Field(5, ge=1, description="Evaluate L_sim every this many iterations.")
    lambda_wrench: float = Field(1.0, ge=0, description="Weight of the wrench residual.")
    lambda_sim: float = Field(10.0, ge=0, description="Weight of L_sim.")
    lambda_anchor: float = Field(0.01, ge=0, description="Weight of the pose anchor.")
    lambda_com: float = Field(0.01, ge=0, description="Weight of the COM shift (per cm^2).")
    anchor_translation_m: float = Field(0.005, gt=0, description="Anchor scale, translation.")
    anchor_rotation_deg: float = Field(3.0, gt=0, description="Anchor scale, rotation.")
