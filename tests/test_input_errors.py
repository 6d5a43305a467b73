"""Bad input: one clear line naming the file and the problem, a non-zero exit, no traceback,
and input/ left exactly as it was."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from conftest import snapshot


def _run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "r2s.cli", *args], capture_output=True,
                          text=True, timeout=120)


def _break_missing_rgb(inp: Path) -> None:
    (inp / "rgb.png").unlink()


def _break_wrong_size(inp: Path) -> None:
    Image.fromarray(np.zeros((10, 10), np.uint8)).save(inp / "masks.png")


def _break_empty_mask(inp: Path) -> None:
    Image.fromarray(np.zeros((48, 64), np.uint8)).save(inp / "masks.png")


def _break_nan_depth(inp: Path) -> None:
    np.save(inp / "depth.npy", np.full((48, 64), np.nan, np.float32))


def _break_depth_8bit(inp: Path) -> None:
    # a depth visualisation saved as 8-bit grey instead of the 16-bit depth
    (inp / "depth.npy").unlink(missing_ok=True)
    Image.fromarray(np.full((48, 64), 120, np.uint8)).save(inp / "depth.png")


def _break_bad_json(inp: Path) -> None:
    (inp / "camera.json").write_text('{"width": 64, "height": 48,, }')


def _break_camera_pose(inp: Path) -> None:
    cam = json.loads((inp / "camera.json").read_text())
    cam["world_from_camera"][0][0] = 5.0
    (inp / "camera.json").write_text(json.dumps(cam))


def _break_unreadable_mesh(inp: Path) -> None:
    (inp / "priors").mkdir()
    (inp / "priors" / "1.glb").write_bytes(b"not a mesh at all")
    (inp / "objects.json").write_text(json.dumps(
        {"objects": [{"id": 1, "prior_mesh": "priors/1.glb"}]}))


def _break_missing_prior(inp: Path) -> None:
    (inp / "objects.json").write_text(json.dumps(
        {"objects": [{"id": 1, "prior_mesh": "priors/nope.glb"}]}))


def _break_bad_object_id(inp: Path) -> None:
    (inp / "objects.json").write_text(json.dumps({"objects": [{"id": -3}]}))


CASES = [
    (_break_missing_rgb, "rgb.png", "missing file"),
    (_break_wrong_size, "masks.png", "wrong size"),
    (_break_empty_mask, "masks.png", "no instance"),
    (_break_nan_depth, "depth.npy", "no valid depth"),
    (_break_depth_8bit, "depth.png", "8-bit"),
    (_break_bad_json, "camera.json", "bad JSON"),
    (_break_camera_pose, "camera.json", "rotation"),
    (_break_unreadable_mesh, "1.glb", "unreadable mesh"),
    (_break_missing_prior, "nope.glb", "missing prior"),
    (_break_bad_object_id, "objects.json", "positive"),
]


@pytest.mark.parametrize("breaker,where,what", CASES, ids=[c[0].__name__[7:] for c in CASES])
def test_bad_input_one_line_nonzero_exit_input_unchanged(tiny_scene: Path, breaker, where, what):
    inp = tiny_scene / "input"
    breaker(inp)
    before = snapshot(inp)
    proc = _run_cli("init", str(tiny_scene))
    assert proc.returncode != 0
    err_lines = [line for line in proc.stderr.strip().splitlines() if line.strip()]
    assert len(err_lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    assert where in err_lines[0] and what in err_lines[0], err_lines[0]
    assert snapshot(inp) == before


def test_missing_scene_dir(tmp_path: Path):
    proc = _run_cli("run", str(tmp_path / "nowhere"))
    assert proc.returncode != 0
    assert "does not exist" in proc.stderr and "Traceback" not in proc.stderr


def test_valid_tiny_scene_loads(tiny_scene: Path):
    from r2s.io.input_scene import load_input

    scene = load_input(tiny_scene)
    assert scene.ids == [1]
    assert scene.depth_m.shape == (48, 64)
    assert np.isclose(np.nanmedian(scene.depth_m[scene.masks == 1]), 0.48)
    assert scene.objects[0].prior_mesh is None
