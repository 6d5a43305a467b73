"""The diagnose benchmark's ``CASE@FACTOR`` cases scale the injected deviation."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "bench_diagnose.py"


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_diagnose_under_test", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_factor_scales_the_deviation_from_the_neutral_value(bench):
    effects, expected = bench.case_spec("depth_scale@3")
    assert float(effects["depth_scale"]) == pytest.approx(1.12, abs=1e-9)
    assert expected == ("depth_scale",)
    effects, _ = bench.case_spec("scale+camera@0.5")
    assert float(effects["depth_scale"]) == pytest.approx(1.02, abs=1e-9)
    assert float(effects["camera_rotation_deg"]) == pytest.approx(1.5, abs=1e-9)
    assert float(bench.case_spec("lens_distortion@0.5")[0]["lens_k1"]) == pytest.approx(-0.06)


def test_no_factor_is_the_case_itself_and_friction_is_not_resized(bench):
    assert bench.case_spec("depth_offset") == bench.CASES["depth_offset"]
    effects, expected = bench.case_spec("offset+friction@2")
    assert float(effects["depth_offset_m"]) == pytest.approx(0.02, abs=1e-12)
    assert effects["friction"] == "0.3"
    assert expected == ("depth_offset", "friction")
    assert bench.base_case("table_tilt@0.5") == "table_tilt"
