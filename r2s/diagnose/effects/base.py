"""What an effect is: a small parametric extension of the scene model.

An effect module defines one :class:`Effect` instance named ``EFFECT``. It says which
residual it explains (``signature``), fits its parameters from the measured
:class:`r2s.diagnose.data.Residuals` (``fit``), predicts the residuals that remain with it
in the model (``EffectFit.residuals_after``), and changes the model: the observation
(``apply_to_input``) and/or the reconstructed state (``apply_to_state``).

Scores are chi-square based: every residual block is normalised by its noise level, so
``sse`` is a chi-square and, relative to the model without the effect,

    delta_BIC = sse_after - sse_before + k * ln(n)

(``k`` parameters, ``n`` residual entries in all blocks). Negative is evidence for the
effect; "no effect" has delta_BIC = 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Optional

import numpy as np

from r2s.diagnose.stats.blocks import blocks_of, total_n, total_sse
from r2s.diagnose.data import Residuals
from r2s.diagnose.stats.noise import noise_bar as registration_noise_bar
from r2s.io.input_scene import Camera, InputScene
from r2s.io.state import SceneState


@dataclass(frozen=True)
class EffectFit:
    """The fitted effect and how much of the residual it explains.

    Attributes
    ----------
    effect : effect name.
    params : JSON-able fitted parameters (what ``--apply`` records in the manifest).
    n_params : free parameters actually fitted (k of the BIC).
    sse_before / residual_sse_after : total normalised SSE of all blocks without / with it.
    n_obs : residual entries in all blocks (n of the BIC).
    size : the headline size of the effect (scale, degrees, metres, ...), for tables.
    size_unit : unit of ``size``.
    residuals_after : the residuals predicted with the effect in the model.
    identifiable : False when the data cannot say anything about this effect.
    note : one line for the report (why not identifiable, what was fitted).
    penalty : prior penalty of the effect in BIC units (``-2 ln prior odds``), added to
        ``delta_bic`` for the ranking (:attr:`score`).
    """

    effect: str
    params: dict
    n_params: int
    sse_before: float
    residual_sse_after: float
    n_obs: int
    size: Optional[float] = None
    size_unit: str = ""
    residuals_after: Optional[Residuals] = field(default=None, repr=False)
    identifiable: bool = True
    note: str = ""
    penalty: float = 0.0
    noise_bar: Optional[float] = None
    """Explained SSE that noise alone reaches (:mod:`r2s.diagnose.stats.noise`; None: not
    measured for this effect). The effect is supported only above it."""

    @property
    def above_noise(self) -> bool:
        return self.noise_bar is None or self.explained_sse > self.noise_bar

    @property
    def explained_sse(self) -> float:
        return self.sse_before - self.residual_sse_after

    @property
    def delta_bic(self) -> float:
        """BIC with the effect minus BIC without it (negative favours the effect)."""
        if not self.identifiable:
            return float("inf")
        return -self.explained_sse + self.n_params * float(np.log(max(self.n_obs, 2)))

    @property
    def score(self) -> float:
        """What the ranking sorts by: ``delta_bic`` plus the effect's prior penalty."""
        return self.delta_bic + self.penalty

    def summary(self) -> dict:
        return {"effect": self.effect, "identifiable": self.identifiable,
                "delta_bic": self.delta_bic if self.identifiable else None,
                "score": self.score if self.identifiable else None, "penalty": self.penalty,
                "explained_sse": self.explained_sse, "sse_before": self.sse_before,
                "sse_after": self.residual_sse_after, "n_params": self.n_params,
                "n_obs": self.n_obs, "size": self.size, "size_unit": self.size_unit,
                "params": self.params, "note": self.note, "noise_bar": self.noise_bar,
                "above_noise": self.above_noise}


def not_identifiable(name: str, res: Residuals, note: str) -> EffectFit:
    blocks = blocks_of(res)
    sse = total_sse(blocks)
    return EffectFit(name, {}, 0, sse, sse, total_n(blocks), identifiable=False, note=note)


def make_fit(name: str, before: Residuals, after: Residuals, params: dict, n_params: int,
             size: Optional[float], size_unit: str, note: str = "") -> EffectFit:
    """An :class:`EffectFit` from the residuals before and the predicted residuals after.

    ``n_obs`` counts the entries of ``before``'s blocks so that every effect of one
    diagnosis is scored with the same ``n``.
    """
    b0, b1 = blocks_of(before), blocks_of(after)
    return EffectFit(name, params, n_params, total_sse(b0), total_sse(b1), total_n(b0),
                     size=size, size_unit=size_unit, residuals_after=after, note=note)


class Effect:
    """Base of the catalogue entries; subclasses override what they change.

    Attributes
    ----------
    name : registry key (also the key in ``manifest.model["effects"]``).
    n_params : nominal number of parameters (per object for per-object effects).
    signature : the residual pattern the effect explains (one paragraph).
    level : "input" when it corrects the observation (init must rerun), "state" when it
        changes the reconstructed state (physics stages must rerun).
    preference : tie-break among effects that explain the data equally (lower first).
    penalty : prior penalty in BIC units (``-2 ln prior odds``): how much more evidence it
        needs than the others, for an effect whose wrong application does harm.
    evidence_block : the block its evidence comes from when noise alone can be redrawn
        there ("registration"), so that a noise bar is measured for it; None otherwise.
    interacts_with : effects whose fits change each other's (refitted jointly).
    quantities : what in the model its parameters set (default: its own name); two
        effects that set a common quantity are one refit of it, not two effects.
    """

    name: str = ""
    n_params: int = 0
    signature: str = ""
    level: Literal["input", "state"] = "state"
    preference: int = 50
    penalty: float = 0.0
    evidence_block: Optional[str] = None
    interacts_with: frozenset = frozenset()

    @property
    def quantities(self) -> frozenset:
        return frozenset({self.name})

    def fit(self, residuals: Residuals) -> EffectFit:
        raise NotImplementedError

    def prior_penalty(self, fit: EffectFit, penalty: float) -> float:
        """The prior penalty (BIC units) of ``fit``, given the effect's ``penalty``: the same
        for every fit unless the effect says otherwise (a per-object effect whose prior odds
        hold for each object it changes)."""
        return penalty

    def apply_to_input(self, scene: InputScene, params: dict) -> InputScene:
        """The observation as this effect says it really is (default: unchanged)."""
        return scene

    def apply_to_camera(self, camera: Camera, params: dict) -> Camera:
        """The camera as this effect says it really is (default: unchanged); the part of
        ``apply_to_input`` that stages reading only ``camera.json`` need (evaluate)."""
        return camera

    def apply_to_state(self, state: SceneState, params: dict) -> SceneState:
        """The reconstructed state with this effect in it (default: unchanged)."""
        return state

    def compose(self, old: dict, new: dict) -> dict:
        """Parameters of applying ``old`` and then ``new`` (default: ``new`` replaces)."""
        return new

    def noise_bar(self, residuals: Residuals, n_params: int, draws: int, quantile: float,
                  seed: int) -> Optional[float]:
        """The explained SSE noise alone reaches for this effect in this scene
        (:func:`r2s.diagnose.stats.noise.noise_bar` over the prior scales; an effect with
        other evidence overrides it)."""
        return registration_noise_bar(lambda r: self.fit(r).explained_sse, residuals,
                                      n_params, draws, quantile, seed)

    def describe(self, params: dict) -> str:
        """One line for the report."""
        return f"{self.name} {params}"


class PerObjectEffect(Effect):
    """An effect with one entry per object: ``params = {"objects": {"<id>": entry}}``.

    Applying it sets each listed object's value with :meth:`apply_entry`; composing keeps
    the old entries and lets the new ones replace those of the same objects.
    """

    def apply_entry(self, obj, entry: dict) -> None:
        """Set the effect's value on one state object from its entry (in place)."""
        raise NotImplementedError

    def apply_to_state(self, state: SceneState, params: dict) -> SceneState:
        new = state.model_copy(deep=True)
        for obj in new.objects:
            entry = params.get("objects", {}).get(str(obj.id))
            if entry is not None:
                self.apply_entry(obj, entry)
        return new

    def compose(self, old: dict, new: dict) -> dict:
        objs = dict(old.get("objects", {}))
        objs.update(new.get("objects", {}))
        return {"objects": objs}
