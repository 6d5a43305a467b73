"""The diagnose benchmark script: ``CASE@FACTOR`` cases scale the injected deviation, and
its decentering lens (``tangential_lens``) moves pixels as Brown's model says: the recorded
pixel at x_d shows the ideal image at the x with x + offset(x) = x_d."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from helpers_scripts import load_script
from r2s.geometry.lens import decentering_offset
from r2s.synth.files import depth_png, write_png

@pytest.fixture(scope="module")
def bench():
    return load_script("bench_diagnose")


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


FX, CX, CY, W, H = 100.0, 31.5, 23.5, 64, 48
P1_P2 = (0.05, -0.08)


def test_the_offset_is_browns_decentering_term():
    x = np.array([[0.2, 0.1]])
    # r^2 = 0.05: dx = 2 p1 x y + p2 (r^2 + 2 x^2), dy = p1 (r^2 + 2 y^2) + 2 p2 x y
    expected = [2 * 0.01 * 0.02 - 0.015 * (0.05 + 0.08), 0.01 * (0.05 + 0.02) - 2 * 0.015 * 0.02]
    assert decentering_offset(x, 0.01, -0.015)[0] == pytest.approx(expected, abs=1e-12)
    assert decentering_offset(np.zeros((1, 2)), 0.01, -0.015)[0] == pytest.approx([0, 0])


def _ideal_scene(root: Path) -> Path:
    """Colour: red = 4 x column, green = 5 x row; depth 0.5 m + 1 mm per column; masks:
    id = 1 + row // 8."""
    inp = root / "input"
    (root / "gt").mkdir(parents=True)
    inp.mkdir()
    (root / "gt" / "scene.json").write_text("{}")
    cam = {"K": [[FX, 0, CX], [0, FX, CY], [0, 0, 1]], "width": W, "height": H,
           "depth_unit_m": 0.0001}
    (inp / "camera.json").write_text(json.dumps(cam))
    rows, cols = np.mgrid[0:H, 0:W]
    rgb = np.stack([4 * cols, 5 * rows, np.zeros_like(cols)], axis=-1).astype(np.uint8)
    write_png(inp / "rgb.png", rgb)
    write_png(inp / "depth.png", depth_png(0.5 + 0.001 * cols, 0.0001))
    write_png(inp / "masks.png", (1 + rows // 8).astype(np.uint8))
    return root


def _ideal_source(u: float, v: float) -> tuple[float, float]:
    """(column, row) of the ideal image that the recorded pixel (u, v) shows, by Newton's
    method on x + offset(x) = x_d (independent of the script's fixed-point iteration)."""
    p1, p2 = P1_P2
    xd = np.array([(u - CX) / FX, (v - CY) / FX])
    x = xd.copy()
    for _ in range(50):
        a, b = x
        r2 = a * a + b * b
        f = x + np.array([2 * p1 * a * b + p2 * (r2 + 2 * a * a),
                          p1 * (r2 + 2 * b * b) + 2 * p2 * a * b]) - xd
        jac = np.eye(2) + np.array([[2 * p1 * b + 6 * p2 * a, 2 * p1 * a + 2 * p2 * b],
                                    [2 * p1 * a + 2 * p2 * b, 6 * p1 * b + 2 * p2 * a]])
        x = x - np.linalg.solve(jac, f)
    return FX * x[0] + CX, FX * x[1] + CY


def test_each_image_shows_the_ideal_image_where_the_lens_sends_it(bench, tmp_path):
    scene = _ideal_scene(tmp_path / "scene")
    bench.add_tangential_lens(scene, P1_P2)
    inp = scene / "input"
    rgb = np.asarray(Image.open(inp / "rgb.png"), dtype=float)
    depth_mm = np.asarray(Image.open(inp / "depth.png"), dtype=float) * 0.1
    masks = np.asarray(Image.open(inp / "masks.png"))
    for u, v in [(5, 40), (58, 6), (50, 30), (31, 23)]:
        col, row = _ideal_source(u, v)
        assert 0 <= col < W and 0 <= row < H
        if (u, v) != (31, 23):
            assert np.hypot(col - u, row - v) > 0.5  # the test points move measurably
        assert rgb[v, u, 0] == pytest.approx(4 * col, abs=1.0)
        assert rgb[v, u, 1] == pytest.approx(5 * row, abs=1.0)
        assert depth_mm[v, u] == pytest.approx(500 + round(col), abs=0.01)
        assert masks[v, u] == 1 + round(row) // 8
    injected = json.loads((scene / "gt" / "scene.json").read_text())["injected_effects"]
    assert injected["tangential_lens"] == {"p1": 0.05, "p2": -0.08}
