"""The lookahead does not credit a path with a second step that refits the first's quantity.

A depth scale and offset fitted together (``depth_bias``) can leave a residual that a
depth offset then takes up: that second step only moves the offset the first one set.
Scored as a two-step path it made ``depth_bias`` win over a depth scale that explained
more on its own (the diagnose benchmark's ``scale+camera`` seed 0 with
``realism=realsense``). Effects and fits here are hand-made: the scores are exact.
"""

from __future__ import annotations

import math

import pytest

from r2s.diagnose.effects import all_effects
from r2s.diagnose.effects.base import Effect, EffectFit
from r2s.diagnose.stats.ranking import rank, second_candidates

N_OBS = 55
LOG_N = math.log(N_OBS)
SSE0 = 100.0


class Scripted(Effect):
    """An effect whose explained SSE is read from a table keyed by the residuals' token
    (the name of the effect already in the model, or "start")."""

    def __init__(self, name: str, n_params: int, explains: dict[str, float],
                 quantities: frozenset):
        self.name = name
        self.n_params = n_params
        self._explains = explains
        self._quantities = quantities

    @property
    def quantities(self) -> frozenset:
        return self._quantities

    def fit(self, residuals) -> EffectFit:
        gain = self._explains.get(residuals, 0.0)
        return EffectFit(self.name, {}, self.n_params, SSE0, SSE0 - gain, N_OBS,
                         residuals_after=self.name)


def _effects(share_quantities: bool) -> dict[str, Effect]:
    bias_q = frozenset({"scale", "offset"}) if share_quantities else frozenset({"bias"})
    return {
        # start: the scale alone explains 30 (score -30 + ln n = -26.0)
        "scale": Scripted("scale", 1, {"start": 30.0}, frozenset({"scale"})),
        # start: scale and offset explain 22 (score -22 + 2 ln n = -14.0) ...
        "bias": Scripted("bias", 2, {"start": 22.0}, bias_q),
        # ... and leave a residual the offset alone takes up (32: score -28.0)
        "offset": Scripted("offset", 1, {"start": 1.0, "bias": 32.0}, frozenset({"offset"})),
    }


def test_a_second_step_on_the_first_steps_own_quantity_does_not_win_the_path():
    lead = rank("start", _effects(share_quantities=True), lookahead=True)
    assert lead.best.effect == "scale"
    assert lead.best.score == pytest.approx(-30.0 + LOG_N, abs=1e-9)
    bias_path = next(p for p in lead.paths if p["first"] == "bias")
    assert bias_path["second"] is None
    assert bias_path["score"] == pytest.approx(-22.0 + 2 * LOG_N, abs=1e-9)


def test_the_same_scripted_data_with_unrelated_quantities_takes_the_two_step_path():
    # the control: were the offset a quantity of its own, the path bias -> offset
    # (-14.0 - 28.0 = -42.0) would beat the scale alone (-26.0)
    lead = rank("start", _effects(share_quantities=False), lookahead=True)
    assert lead.best.effect == "bias"
    bias_path = next(p for p in lead.paths if p["first"] == "bias")
    assert bias_path["second"] == "offset"
    assert bias_path["score"] == pytest.approx(-22.0 + 2 * LOG_N - 32.0 + LOG_N, abs=1e-9)


def test_the_catalogue_keeps_depth_bias_apart_from_its_own_parts():
    effects = all_effects()
    after_bias = second_candidates("depth_bias", effects)
    assert "depth_scale" not in after_bias and "depth_offset" not in after_bias
    assert "camera_rotation" in after_bias and "lens_distortion" in after_bias
    # a scale then an offset are two quantities: that path stays open
    assert "depth_offset" in second_candidates("depth_scale", effects)
    assert "depth_bias" not in second_candidates("depth_scale", effects)


def test_the_lookahead_follows_the_fourth_leader_to_the_best_path():
    # the benchmark's scale+camera@0.5 seed 2 in miniature: three one-step effects lead,
    # and the scale that, with the camera after it, explains most comes fourth
    def one(name, explains):
        return Scripted(name, 1, explains, frozenset({name}))

    effects = {"focal": one("focal", {"start": 40.0}), "offset": one("offset", {"start": 35.0}),
               "tilt": one("tilt", {"start": 33.0}), "scale": one("scale", {"start": 30.0}),
               "camera": one("camera", {"start": 5.0, "scale": 30.0})}
    lead = rank("start", effects, lookahead=True)
    assert lead.best.effect == "scale"
    scale_path = next(p for p in lead.paths if p["first"] == "scale")
    assert scale_path["second"] == "camera"
    assert scale_path["score"] == pytest.approx(-60.0 + 2 * LOG_N, abs=1e-9)
    assert len(lead.paths) == 4  # the camera alone (-5 + ln n) is not supported
    # without the lookahead the greedy leader stands
    assert rank("start", effects, lookahead=False).best.effect == "focal"
