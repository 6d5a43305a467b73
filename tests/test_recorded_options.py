"""One reading of "recorded options, else defaults" for `r2s run`, `r2s STAGE --set` and
the libraries (diagnose reading export's body parameters)."""

from __future__ import annotations

import pytest
from pydantic import Field

from r2s.errors import R2SError
from r2s.io.manifest import Manifest, StageRecord
from r2s.io.recorded_options import recorded_options
from r2s.runner.base import StageOptions, StageSpec
from r2s.runner.pipeline import stage_options
from r2s.sim.export_scene import BodyParams


class _Options(StageOptions):
    iterations: int = Field(10, ge=1)
    step_m: float = 0.01


SPEC = StageSpec("toy", _Options, lambda *a: [], lambda ctx: {})


def _manifest(options: dict) -> Manifest:
    return Manifest(stages={"toy": StageRecord(status="done", options=options)})


def test_overrides_apply_on_top_of_the_recorded_options():
    m = _manifest({"iterations": 50, "step_m": 0.02})
    assert stage_options(SPEC, m, {}) == _Options(iterations=50, step_m=0.02)
    # `--set step_m=0.5` keeps the recorded iterations (it used to restart from 10)
    assert stage_options(SPEC, m, {"step_m": "0.5"}) == _Options(iterations=50, step_m=0.5)


def test_defaults_when_never_ran_or_the_record_no_longer_validates():
    assert stage_options(SPEC, Manifest(), {"iterations": "3"}) == _Options(iterations=3)
    stale = _manifest({"iterations": 0, "step_m": 0.02})  # violates ge=1 today
    assert stage_options(SPEC, stale, {}) == _Options()
    # a record with a key this version dropped keeps the keys it still knows
    renamed = _manifest({"iterations": 7, "old_key": 1})
    assert stage_options(SPEC, renamed, {}) == _Options(iterations=7)


def test_a_bad_override_is_one_clear_error():
    with pytest.raises(R2SError, match="toy option iterations"):
        stage_options(SPEC, Manifest(), {"iterations": "0"})


def test_a_library_reads_the_recorded_subset_into_its_own_type():
    m = Manifest(stages={"export": StageRecord(status="done", options={
        "source": "physopt", "density_kg_m3": 750.0, "max_convex_pieces": 8})})
    params = recorded_options(m, "export", BodyParams)
    assert params.density_kg_m3 == 750.0 and params.convex.max_pieces == 8
    assert params.default_friction == BodyParams().default_friction
    assert recorded_options(Manifest(), "export", BodyParams) == BodyParams()
