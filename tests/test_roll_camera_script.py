"""scripts/roll_camera.py: a rolled copy of a scene shows the same world points."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from helpers_init import SynthObject, default_camera, pose, write_input_scene
from helpers_scripts import load_script
from r2s.geometry.camera import backproject
from r2s.io.input_scene import load_input


@pytest.fixture(scope="module")
def roll():
    return load_script("roll_camera")


def _points_by_id(scene: Path) -> dict[int, np.ndarray]:
    """World points of every instance, sorted so that two copies compare row by row."""
    view = load_input(scene)
    out = {}
    for i in view.ids:
        pts = backproject(view.depth_m, view.camera.K, view.camera.world_from_camera,
                          view.masks == i)
        out[i] = pts[np.lexsort(np.round(pts, 9).T[::-1])]
    return out


@pytest.mark.parametrize("turns", [1, 2, 3])
def test_a_rolled_copy_back_projects_to_the_same_world_points(tmp_path, roll, turns):
    # an off-centre principal point and non-square pixels, so that a swapped pair shows
    K, world_from_camera = default_camera(160, 120)
    K = K.copy()
    K[0, 0] *= 1.05
    K[0, 2] += 7.0
    K[1, 2] -= 4.0
    objects = [SynthObject(1, trimesh.creation.box((0.06, 0.04, 0.05)), pose([0.02, 0.0, 0.025])),
               SynthObject(2, trimesh.creation.icosphere(2, 0.025), pose([-0.05, 0.03, 0.025]),
                           (60, 60, 200))]
    src = write_input_scene(tmp_path / "src", objects, K=K, world_from_camera=world_from_camera)
    dst = tmp_path / "dst"
    roll.roll_scene(src, dst, turns)
    before, after = _points_by_id(src), _points_by_id(dst)
    assert before.keys() == after.keys() == {1, 2}
    for i in before:
        assert len(before[i]) > 50 and before[i].shape == after[i].shape
        np.testing.assert_allclose(after[i], before[i], atol=1e-9)
    shape = load_input(dst).masks.shape
    assert shape == ((160, 120) if turns % 2 else (120, 160))


def test_an_existing_destination_is_refused(tmp_path, roll):
    (tmp_path / "dst").mkdir()
    with pytest.raises(SystemExit, match="exists"):
        roll.roll_scene(tmp_path / "src", tmp_path / "dst", 1)


def test_a_folder_that_is_not_a_scene_is_refused_in_one_line(tmp_path, roll):
    (tmp_path / "src").mkdir()
    with pytest.raises(SystemExit, match="camera.json: not found") as info:
        roll.roll_scene(tmp_path / "src", tmp_path / "dst", 1)
    assert "\n" not in str(info.value) and not (tmp_path / "dst").exists()
